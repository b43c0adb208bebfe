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
>>> IdentificationSettings(iqr_k=-1)  # doctest: +NORMALIZE_WHITESPACE
Traceback (most recent call last):
...
nmsid.analysis.errors.SettingError: (in code): iqr_k = -1 is not valid: a value > 0
(the outlier fence's width in IQRs; 1.5 in the paper)
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Annotated, Literal

from pydantic import Field, StrictBool, StrictFloat, StrictInt, model_validator

from nmsid.analysis.errors import setting_error
from nmsid.analysis.qc.settings import QCSettings
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass


class InputHold(enum.StrEnum):
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


class InputTiming(enum.StrEnum):
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


class NoiseLevel(enum.StrEnum):
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
MAX_INPUT_DELAY_S = 0.05
"""A rig's input delay is sub-millisecond; 50 ms is physiology (gap diagnosis), not timing."""

Seconds = Annotated[StrictFloat, Field(ge=0.0, le=3600.0, description=(
    "a time in the trial, at most an hour"))]
Delay = Annotated[StrictFloat, Field(gt=-MAX_INPUT_DELAY_S, lt=MAX_INPUT_DELAY_S, description=(
    "a calibrated input delay below 0.05 s in size"))]


@settings_dataclass(setting_error)
class IdentificationSettings:
    """Settings of preprocessing, fitting and model selection (defaults follow the paper).

    Attributes are documented inline; ``docs/identification.md`` gives each reason.
    """

    # -- preprocessing ------------------------------------------------------------
    detrend: StrictBool = True
    """Remove a least-squares line from each raw trial (paper: "detrended to remove linear
    drift"). Done on the whole raw trial, lead-in included, as the paper describes."""
    window_start_s: Seconds | None = None
    """Start of the analysed window in s after stimulation onset; None = the trial's
    ``steady_s`` (5 s in the paper)."""
    window_end_s: Seconds | None = None
    """End of the window; None = ``steady_s + chirp_s`` (or the end of the data)."""
    savgol_window: StrictInt | None = bounded(41, ge=3, le=100_001, why=(
        "an odd window of 3 samples up to 100,001"))
    """Savitzky-Golay window in samples (odd), None to skip (paper: 41)."""
    savgol_order: StrictInt = bounded(3, ge=0, le=20, why="a polynomial order up to 20")
    """Savitzky-Golay polynomial order (paper: 3)."""
    lowpass_Hz: StrictFloat | None = bounded(25.0, gt=0.0, le=100_000.0, why=(
        "a cut-off frequency below 100 kHz"))
    """Butterworth low-pass cut-off, None to skip (paper: 25 Hz)."""
    butter_order: StrictInt = bounded(4, ge=1, le=12, why=(
        "higher Butterworth orders are numerically fragile"))
    """Butterworth order (paper: not stated). 4 gives, run forward and backward, an
    8th-order magnitude roll-off: 50 Hz mains pick-up is attenuated 257x while the chirp
    band (<= 10 Hz) is passed within 0.07 %."""
    zero_phase: StrictBool = True
    """Filter forward and backward (``sosfiltfilt``). A causal 25 Hz Butterworth delays
    the force by 10-20 ms, which biases wn and zeta; zero phase has no delay."""
    prefilter_input: StrictBool = True
    """Apply the same smoothing and low-pass to rE as to the force. Filtering input and
    output with the same linear filter leaves G unchanged (F y = G F u), so the small
    in-band attenuation of the filters cannot bias Kp, wn or zeta."""
    filter_whole_trial: StrictBool = True
    """Filter the whole detrended trial and cut the window afterwards (True), instead of
    cutting first as the paper's wording orders it (False). Inside the window the result is
    the same; cutting afterwards keeps the filters' start-up transients out of the
    window (before the window rE is constant and the force at rest). The filters start
    max(0.5 s, 10 / lowpass_Hz) before the window: their memory is far shorter."""
    edge_trim_s: Seconds | None = None
    """Data dropped where the window meets an edge of the filtered record (the end of the
    trial; also the window start when ``filter_whole_trial`` is False). Zero-phase
    filtering pads each signal by reflection, which is not consistent with G between rE
    and force, so the last ~2.5/lowpass_Hz s are slightly wrong (bias ~4e-4 in Kp for a
    lightly damped system). None: automatic, 3 / lowpass_Hz + half the Savitzky-Golay
    window (0.13 s with the paper's filters: 1.3 % of the chirp; bias < 2e-6)."""
    fit_fs_Hz: StrictFloat | None = bounded(200.0, gt=0.0, le=100_000.0, why=(
        "a fit rate below 100 kHz"))
    """Rate at which the model is fitted: the filtered data are decimated by
    floor(fs_Hz / fit_fs_Hz). After a 25 Hz low-pass nothing above ~40 Hz is left, so 200 Hz
    keeps all the information and makes the fit 10x cheaper. None: fit at the raw rate.
    Must be at least 4x ``lowpass_Hz``."""
    input_hold: InputHold = InputHold.SMOOTH
    """How the model sees the input between samples at the fit rate (see
    :class:`InputHold`); the rig's own timing is ``input_timing``."""
    input_timing: InputTiming | Delay = bounded(InputTiming.ESTIMATE, why=(
        "'estimate', 'hold', 'smooth' or a calibrated delay in s below 0.05 in size"))
    """The input-timing model, shared by identification and gap diagnosis (see
    :class:`InputTiming`): ``"estimate"`` (default: rigs differ, e.g. our simulated
    stimulator holds each sample, a DAC with a reconstruction filter does not; estimating
    costs one extra fit only where the delay is significant), ``"hold"``, ``"smooth"``, or
    a delay in s calibrated for the rig (positive: the stimulation lags the rE record)."""
    input_timing_max_s: StrictFloat = bounded(1e-3, gt=0.0, lt=MAX_INPUT_DELAY_S, why=(
        "sub-millisecond timing is the rig's; longer latencies are physiology"))
    """Largest delay (either sign) the estimate may take: sub-millisecond timing is what
    a rig's sampling and output stage produce (a one-sample hold at 1 kHz is 0.5 ms);
    longer latencies are physiology (``dead_time`` in the gap diagnosis)."""

    # -- trial quality control ------------------------------------------------------
    qc: StrictBool = True
    """Judge every trial before averaging (:mod:`nmsid.analysis.qc`) and average and fit only
    the trials it keeps (repaired data where an artefact was bridged). The paper averages
    every repeat; one voluntary contraction in one repeat then moves Kp and zeta by ~1 %
    (ten standard errors). False: the paper's plain average of every completed repeat."""
    qc_settings: QCSettings = Field(default_factory=QCSettings)
    """Thresholds of the trial quality control (:class:`nmsid.analysis.qc.QCSettings`)."""

    # -- fitting ------------------------------------------------------------------
    estimate_trend: StrictBool = True
    """Estimate an output ramp (c1 t) along with the output offset and initial state.
    The paper's detrend fits its line to drift + response together, so part of the
    response's own mean leaks into the window as a ramp; a ramp term absorbs it exactly
    and any drift the detrend missed. MATLAB tfest estimates offset and initial state."""
    max_iterations: StrictInt = bounded(100, ge=1, le=100_000, why=(
        "a search that has not converged in 100,000 iterations will not"))
    """Iteration limit of the prediction-error (Gauss-Newton / Levenberg-Marquardt) search."""
    tolerance: StrictFloat = bounded(1e-10, gt=0.0, lt=1.0, why="a relative tolerance")
    """Stop when the relative cost decrease and the relative step are below this."""
    retry_below_fit_pct: StrictFloat = bounded(70.0, ge=-1e6, le=100.0, why=(
        "a fit percent (100 is perfect)"))
    """If the fit from the instrumental-variable start ends below this fit percent (or does
    not converge), also start from a coarse grid of (wn, zeta) and keep the best."""
    noise_level: NoiseLevel = NoiseLevel.BAND_PSD
    """How standard errors estimate the noise (see :class:`NoiseLevel`)."""
    resid_lags: StrictInt = bounded(25, ge=1, le=10_000, why="lags of the residual tests")
    """Lags of the residual tests (MATLAB ``resid`` default: 25)."""
    resid_confidence: StrictFloat = bounded(0.99, gt=0.0, lt=1.0, why="a probability")
    """Confidence of the residual tests' bounds (MATLAB ``resid`` default: 99 %)."""

    # -- model selection ----------------------------------------------------------
    models: tuple[Literal["linear", "quadratic", "exponential"], ...] = bounded(
        MODEL_NAMES, min_length=1, max_length=3, why=f"a non-empty subset of {MODEL_NAMES}")
    """Candidate curves of a parameter against sE."""
    iqr_k: StrictFloat = bounded(1.5, gt=0.0, le=100.0, why=(
        "the outlier fence's width in IQRs; 1.5 in the paper"))
    """Outliers are outside [Q1 - k IQR, Q3 + k IQR] (paper: 1.5)."""
    iqr_parameters: tuple[Literal["Kp", "wn_rad_s", "zeta"], ...] = ("wn_rad_s", "zeta")
    """Parameters cleaned of IQR outliers before selection (paper: wn and zeta, not Kp)."""
    aicc_count_noise_variance: StrictBool = False
    """Count the residual variance as a parameter in AICc (k + 1) or not (k = number of
    curve coefficients, as MATLAB's ``aic(..., 'AICc')`` counts only estimated model
    coefficients). Burnham & Anderson count it; the selection rarely changes, the values do."""
    extra: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)
    """Free-form notes (stored with the outputs; not used)."""

    @model_validator(mode="after")
    def _consistent(self):
        if self.savgol_window is not None:
            if self.savgol_window % 2 == 0:
                raise SettingProblem("savgol_window", self.savgol_window,
                                     "an odd integer >= 3, or None")
            if not self.savgol_order < self.savgol_window:
                raise SettingProblem("savgol_order", self.savgol_order,
                                     f"an integer in [0, savgol_window) = "
                                     f"[0, {self.savgol_window})")
        if self.fit_fs_Hz is not None:
            if self.lowpass_Hz is None:
                raise SettingProblem("fit_fs_Hz", self.fit_fs_Hz, "None when lowpass_Hz is "
                                     "None (decimating unfiltered data aliases)")
            if self.fit_fs_Hz < 4 * self.lowpass_Hz:
                raise SettingProblem("fit_fs_Hz", self.fit_fs_Hz,
                                     f">= 4 x lowpass_Hz = {4 * self.lowpass_Hz:g} Hz, or None")
        if (self.window_start_s is not None and self.window_end_s is not None
                and self.window_end_s <= self.window_start_s):
            raise SettingProblem("window_end_s", self.window_end_s,
                                 f"a time after window_start_s = {self.window_start_s}")
        return self

    def edge_trim_samples(self, fs_Hz: float) -> int:
        """Samples dropped at a filtered edge (see ``edge_trim_s``)."""
        if self.edge_trim_s is not None:
            return int(round(self.edge_trim_s * fs_Hz))
        trim = 3.0 / self.lowpass_Hz if self.lowpass_Hz else 0.0
        half_sg = (self.savgol_window // 2) if self.savgol_window else 0
        return int(round(trim * fs_Hz)) + half_sg

    def replace(self, **changes) -> IdentificationSettings:
        """A copy with some settings changed (validated again; :class:`SettingError`)."""
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
            elif dataclasses.is_dataclass(value) and not isinstance(value, type):
                value = dataclasses.asdict(value)
            out[f.name] = value
        return out
