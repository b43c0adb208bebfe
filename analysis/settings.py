"""Every choice of the identification that the paper leaves open, as one dataclass.

The paper ("Parameter estimation") says: detrend the raw force, keep t >= 5 s, smooth with
a third-order Savitzky-Golay filter (41 samples), low-pass with a 25 Hz Butterworth filter,
average the three repeats, fit a second-order transfer function with MATLAB; then model
Kp, wn and zeta against sE (linear / quadratic / exponential, AICc), removing IQR outliers
of wn and zeta first. Everything else is a setting here, each with its default and the
reason for it (``docs/identification.md`` has the long form).

Examples
--------
>>> s = IdentificationSettings(butter_order=2)
>>> s.lowpass_Hz
25.0
>>> IdentificationSettings(iqr_k=-1)
Traceback (most recent call last):
...
analysis.errors.SettingError: iqr_k = -1 is not valid: use a number > 0 (1.5 in the paper)
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field

from nmsid.analysis.errors import SettingError
from nmsid.analysis.qc.settings import QCSettings


class InputHold(str, enum.Enum):
    """How the simulator interprets the sampled input between samples.

    ``SMOOTH``: rE is a sampled smooth (band-limited) signal. Piecewise-linear (first-order
    hold) with the input pre-corrected by the 5-tap FIR
    ``v = u - D2(u)/12 + D4(u)/90`` (D2, D4 central differences), which cancels the
    hold's sinc^2 attenuation to sixth order in f/fs: error below 1e-6 at 10 Hz even at
    a 200 Hz fit rate.
    ``LINEAR``: exactly piecewise linear between samples (MATLAB/scipy ``lsim``
    'foh'); right for data generated that way, error ~(pi f/fs)^2/3 for smooth signals.
    """

    SMOOTH = "smooth"
    LINEAR = "linear"


class InputTiming(str, enum.Enum):
    """How the rig turns the recorded rE samples into stimulation (the input-timing model).

    ``ESTIMATE``: no built-in belief; the sub-millisecond delay between the rE record and
    the stimulation (either sign) is estimated from the data (see
    :mod:`nmsid.analysis.input_timing`), within +-``input_timing_max_s``.
    ``HOLD``: the stimulator holds each sample for one sample period (zero-order hold:
    sample k applied from k / fs_Hz on), i.e. the input lags the record by half a sample.
    ``SMOOTH``: the record is the stimulation (a smooth, band-limited input; no delay).
    A number of seconds instead of a name is a delay calibrated per rig (either sign).
    """

    ESTIMATE = "estimate"
    HOLD = "hold"
    SMOOTH = "smooth"


class NoiseLevel(str, enum.Enum):
    """How the noise level behind the standard errors is estimated.

    ``BAND_PSD``: the residual's power spectral density averaged over the chirp band,
    expressed as the variance of an equivalent white noise at the fit rate. Correct when
    residuals are coloured, which they always are after the 25 Hz low-pass.
    ``WHITE``: the plain residual variance RSS/(N - p), as a textbook (and MATLAB) does;
    with low-passed data it understates the standard errors (about 2x at a 200 Hz fit
    rate and 25 Hz cut-off) because neighbouring samples are not independent.
    """

    BAND_PSD = "band_psd"
    WHITE = "white"


MODEL_NAMES = ("linear", "quadratic", "exponential")
PARAMETER_NAMES = ("Kp", "wn_rad_s", "zeta")


@dataclass(frozen=True)
class IdentificationSettings:
    """Settings of preprocessing, fitting and model selection (defaults follow the paper).

    Attributes are documented inline; ``docs/identification.md`` gives each reason.
    """

    # -- preprocessing ------------------------------------------------------------
    detrend: bool = True
    """Remove a least-squares line from each raw trial (paper: "detrended to remove linear
    drift"). Done on the whole raw trial, lead-in included, as the paper describes."""
    window_start_s: float | None = None
    """Start of the analysed window in s after stimulation onset; None = the trial's
    ``steady_s`` (5 s in the paper)."""
    window_end_s: float | None = None
    """End of the window; None = ``steady_s + chirp_s`` (or the end of the data)."""
    savgol_window: int | None = 41
    """Savitzky-Golay window in samples (odd), None to skip (paper: 41)."""
    savgol_order: int = 3
    """Savitzky-Golay polynomial order (paper: 3)."""
    lowpass_Hz: float | None = 25.0
    """Butterworth low-pass cut-off, None to skip (paper: 25 Hz)."""
    butter_order: int = 4
    """Butterworth order (paper: not stated). 4 gives, run forward and backward, an
    8th-order magnitude roll-off: 50 Hz mains pick-up is attenuated 257x while the chirp
    band (<= 10 Hz) is passed within 0.07 %."""
    zero_phase: bool = True
    """Filter forward and backward (``sosfiltfilt``). A causal 25 Hz Butterworth delays
    the force by 10-20 ms, which biases wn and zeta; zero phase has no delay."""
    prefilter_input: bool = True
    """Apply the same smoothing and low-pass to rE as to the force. Filtering input and
    output with the same linear filter leaves G unchanged (F y = G F u), so the small
    in-band attenuation of the filters cannot bias Kp, wn or zeta."""
    filter_whole_trial: bool = True
    """Filter the whole detrended trial and cut the window afterwards (True), instead of
    cutting first as the paper's wording orders it (False). Inside the window the result is
    the same; cutting afterwards keeps the filters' start-up transients out of the
    window (before the window rE is constant and the force at rest). The filters start
    max(0.5 s, 10 / lowpass_Hz) before the window: their memory is far shorter."""
    edge_trim_s: float | None = None
    """Data dropped where the window meets an edge of the filtered record (the end of the
    trial; also the window start when ``filter_whole_trial`` is False). Zero-phase
    filtering pads each signal by reflection, which is not consistent with G between rE
    and force, so the last ~2.5/lowpass_Hz s are slightly wrong (bias ~4e-4 in Kp for a
    lightly damped system). None: automatic, 3 / lowpass_Hz + half the Savitzky-Golay
    window (0.13 s with the paper's filters: 1.3 % of the chirp; bias < 2e-6)."""
    fit_fs_Hz: float | None = 200.0
    """Rate at which the model is fitted: the filtered data are decimated by
    floor(fs_Hz / fit_fs_Hz). After a 25 Hz low-pass nothing above ~40 Hz is left, so 200 Hz
    keeps all the information and makes the fit 10x cheaper. None: fit at the raw rate.
    Must be at least 4x ``lowpass_Hz``."""
    input_hold: InputHold = InputHold.SMOOTH
    """How the model sees the input between samples at the fit rate (see
    :class:`InputHold`); the rig's own timing is ``input_timing``."""
    input_timing: InputTiming | float = InputTiming.ESTIMATE
    """The input-timing model, shared by identification and gap diagnosis (see
    :class:`InputTiming`): ``"estimate"`` (default: rigs differ, e.g. our simulated
    stimulator holds each sample, a DAC with a reconstruction filter does not; estimating
    costs one extra fit only where the delay is significant), ``"hold"``, ``"smooth"``, or
    a delay in s calibrated for the rig (positive: the stimulation lags the rE record)."""
    input_timing_max_s: float = 1e-3
    """Largest delay (either sign) the estimate may take: sub-millisecond timing is what
    a rig's sampling and output stage produce (a one-sample hold at 1 kHz is 0.5 ms);
    longer latencies are physiology (``dead_time`` in the gap diagnosis)."""

    # -- trial quality control ------------------------------------------------------
    qc: bool = True
    """Judge every trial before averaging (:mod:`nmsid.analysis.qc`) and average and fit only
    the trials it keeps (repaired data where an artefact was bridged). The paper averages
    every repeat; one voluntary contraction in one repeat then moves Kp and zeta by ~1 %
    (ten standard errors). False: the paper's plain average of every completed repeat."""
    qc_settings: QCSettings = field(default_factory=QCSettings)
    """Thresholds of the trial quality control (:class:`nmsid.analysis.qc.QCSettings`)."""

    # -- fitting ------------------------------------------------------------------
    estimate_trend: bool = True
    """Estimate an output ramp (c1 t) along with the output offset and initial state.
    The paper's detrend fits its line to drift + response together, so part of the
    response's own mean leaks into the window as a ramp; a ramp term absorbs it exactly
    and any drift the detrend missed. MATLAB tfest estimates offset and initial state."""
    max_iterations: int = 100
    """Iteration limit of the prediction-error (Gauss-Newton / Levenberg-Marquardt) search."""
    tolerance: float = 1e-10
    """Stop when the relative cost decrease and the relative step are below this."""
    retry_below_fit_pct: float = 70.0
    """If the fit from the instrumental-variable start ends below this fit percent (or does
    not converge), also start from a coarse grid of (wn, zeta) and keep the best."""
    noise_level: NoiseLevel = NoiseLevel.BAND_PSD
    """How standard errors estimate the noise (see :class:`NoiseLevel`)."""
    resid_lags: int = 25
    """Lags of the residual tests (MATLAB ``resid`` default: 25)."""
    resid_confidence: float = 0.99
    """Confidence of the residual tests' bounds (MATLAB ``resid`` default: 99 %)."""

    # -- model selection ----------------------------------------------------------
    models: tuple[str, ...] = MODEL_NAMES
    """Candidate curves of a parameter against sE."""
    iqr_k: float = 1.5
    """Outliers are outside [Q1 - k IQR, Q3 + k IQR] (paper: 1.5)."""
    iqr_parameters: tuple[str, ...] = ("wn_rad_s", "zeta")
    """Parameters cleaned of IQR outliers before selection (paper: wn and zeta, not Kp)."""
    aicc_count_noise_variance: bool = False
    """Count the residual variance as a parameter in AICc (k + 1) or not (k = number of
    curve coefficients, as MATLAB's ``aic(..., 'AICc')`` counts only estimated model
    coefficients). Burnham & Anderson count it; the selection rarely changes, the values do."""
    extra: dict = field(default_factory=dict, compare=False, repr=False)
    """Free-form notes (stored with the outputs; not used)."""

    def __post_init__(self):
        problems = list(self._problems())
        if problems:
            raise SettingError(problems[0])

    def _problems(self):
        def bad(name, value, valid):
            return f"{name} = {value!r} is not valid: use {valid}"

        if self.savgol_window is not None:
            if (not isinstance(self.savgol_window, int) or self.savgol_window < 3
                    or self.savgol_window % 2 == 0):
                yield bad("savgol_window", self.savgol_window, "an odd integer >= 3, or None")
            elif not 0 <= self.savgol_order < self.savgol_window:
                yield bad("savgol_order", self.savgol_order,
                          f"an integer in [0, savgol_window) = [0, {self.savgol_window})")
        if self.lowpass_Hz is not None and not (self.lowpass_Hz > 0):
            yield bad("lowpass_Hz", self.lowpass_Hz, "a frequency > 0 in Hz, or None")
        if not isinstance(self.butter_order, int) or not 1 <= self.butter_order <= 12:
            yield bad("butter_order", self.butter_order, "an integer from 1 to 12")
        if self.fit_fs_Hz is not None:
            if not (self.fit_fs_Hz > 0):
                yield bad("fit_fs_Hz", self.fit_fs_Hz, "a rate > 0 in Hz, or None")
            elif self.lowpass_Hz is None:
                yield bad("fit_fs_Hz", self.fit_fs_Hz,
                          "None when lowpass_Hz is None (decimating unfiltered data aliases)")
            elif self.fit_fs_Hz < 4 * self.lowpass_Hz:
                yield bad("fit_fs_Hz", self.fit_fs_Hz,
                          f">= 4 x lowpass_Hz = {4 * self.lowpass_Hz:g} Hz, or None")
        if self.edge_trim_s is not None and not (self.edge_trim_s >= 0):
            yield bad("edge_trim_s", self.edge_trim_s, "a time >= 0 in s, or None (automatic)")
        for name in ("window_start_s", "window_end_s"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                yield bad(name, value, "a time >= 0 in s, or None")
        if (self.window_start_s is not None and self.window_end_s is not None
                and self.window_end_s <= self.window_start_s):
            yield bad("window_end_s", self.window_end_s,
                      f"a time after window_start_s = {self.window_start_s}")
        if not isinstance(self.max_iterations, int) or self.max_iterations < 1:
            yield bad("max_iterations", self.max_iterations, "an integer >= 1")
        if not 0 < self.tolerance < 1:
            yield bad("tolerance", self.tolerance, "a number in (0, 1)")
        if not isinstance(self.resid_lags, int) or self.resid_lags < 1:
            yield bad("resid_lags", self.resid_lags, "an integer >= 1")
        if not 0 < self.resid_confidence < 1:
            yield bad("resid_confidence", self.resid_confidence, "a probability in (0, 1)")
        if not (self.iqr_k > 0):
            yield bad("iqr_k", self.iqr_k, "a number > 0 (1.5 in the paper)")
        for m in self.models:
            if m not in MODEL_NAMES:
                yield bad("models", self.models, f"a subset of {MODEL_NAMES}")
                break
        if not self.models:
            yield bad("models", self.models, f"a non-empty subset of {MODEL_NAMES}")
        for p in self.iqr_parameters:
            if p not in PARAMETER_NAMES:
                yield bad("iqr_parameters", self.iqr_parameters, f"a subset of {PARAMETER_NAMES}")
                break
        if isinstance(self.input_timing, (int, float)) and not isinstance(
                self.input_timing, bool):
            if not (math.isfinite(self.input_timing) and abs(self.input_timing) < 0.05):
                yield bad("input_timing", self.input_timing,
                          "'estimate', 'hold', 'smooth' or a delay in s below 0.05 in size")
            else:
                object.__setattr__(self, "input_timing", float(self.input_timing))
        elif not isinstance(self.input_timing, InputTiming):
            try:
                object.__setattr__(self, "input_timing", InputTiming(self.input_timing))
            except ValueError:
                yield bad("input_timing", self.input_timing,
                          f"one of {[k.value for k in InputTiming]} or a delay in s")
        if not (0 < self.input_timing_max_s < 0.05):
            yield bad("input_timing_max_s", self.input_timing_max_s, "a time in (0, 0.05) s")
        # enums given as strings (e.g. from JSON) are converted, bad ones rejected
        for name, kind in (("input_hold", InputHold), ("noise_level", NoiseLevel)):
            value = getattr(self, name)
            if not isinstance(value, kind):
                try:
                    object.__setattr__(self, name, kind(value))
                except ValueError:
                    yield bad(name, value, f"one of {[k.value for k in kind]}")

    def edge_trim_samples(self, fs_Hz: float) -> int:
        """Samples dropped at a filtered edge (see ``edge_trim_s``)."""
        if self.edge_trim_s is not None:
            return int(round(self.edge_trim_s * fs_Hz))
        trim = 3.0 / self.lowpass_Hz if self.lowpass_Hz else 0.0
        half_sg = (self.savgol_window // 2) if self.savgol_window else 0
        return int(round(trim * fs_Hz)) + half_sg

    def replace(self, **changes) -> IdentificationSettings:
        """A copy with some settings changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        """JSON-ready dict of every setting (stored with the outputs)."""
        out = {}
        for f in dataclasses.fields(self):
            if f.name == "extra":
                continue
            value = getattr(self, f.name)
            if isinstance(value, enum.Enum):
                value = value.value
            elif isinstance(value, tuple):
                value = list(value)
            elif dataclasses.is_dataclass(value):
                value = dataclasses.asdict(value)
            out[f.name] = value
        return out
