"""Trials of one sE level -> the windowed, detrended, filtered (t, u, y) that is fitted.

The paper's order: detrend the raw force (linear), keep t >= steady_s, Savitzky-Golay
(order 3, 41 samples), Butterworth low-pass 25 Hz, average the repeats. Every step is
linear, so averaging the detrended repeats first and filtering the average once gives the
same numbers as filtering each repeat, at a third of the cost. The filters run on the
whole trial and the window is cut afterwards (``IdentificationSettings.filter_whole_trial``);
rE gets the same filters as the force (``prefilter_input``), so G is untouched by them.
Finally the data are decimated to ``fit_fs_Hz`` (after the low-pass nothing is lost) and
the input's window mean is removed: u = rE - mean(rE over the window).

Before any of this, rE is moved by the rig's input timing (``input_delay_s``, see
:mod:`nmsid.analysis.input_timing`): a fractional delay of either sign at the raw rate, so that
u is the stimulation the participant received rather than the record of its command. The
gap diagnosis (:mod:`nmsid.analysis.gap.data`) uses the same filters, through
:func:`smooth_and_lowpass`, and the same timing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import convolve1d
from scipy.signal import butter, savgol_coeffs, sosfilt, sosfilt_zi, sosfiltfilt

from nmsid.analysis.discretize import fractional_delay
from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.settings import IdentificationSettings, InputTiming
from nmsid.analysis.thin_lstsq import dot
from nmsid.protocols.reprs import html_repr, names, short_repr


@dataclass
class LevelData:
    """The preprocessed signals of one sE level, ready for :func:`fit_second_order`."""

    sE: float
    t_s: np.ndarray
    """Sample times in s after stimulation onset."""
    u: np.ndarray
    """rE minus its mean over the window (dimensionless)."""
    y_N: np.ndarray
    """Detrended, filtered force averaged over the repeats, in N."""
    fs_Hz: float
    """Rate of ``t_s``/``u``/``y_N`` (after decimation)."""
    raw_fs_Hz: float
    n_trials: int
    trial_names: list[str] = field(default_factory=list)
    band_Hz: tuple[float, float] = (1.0, 10.0)
    """Chirp band (f0, f1) of the trials."""
    rE_mean: float = 0.5
    """Mean of rE over the window (removed from u)."""
    input_delay_s: float = 0.0
    """Delay applied to rE before filtering (the rig's input timing)."""
    baseline_N: float = float("nan")
    """Mean raw force (not detrended) over the second half of the lead-in, where
    rE = 0.5 and the force has settled: the force at rE = 0.5 for this sE."""

    def __repr__(self) -> str:
        return short_repr("LevelData", f"sE {self.sE:g}",
                          f"{self.n_trials} trial(s) {names(self.trial_names)}".rstrip(),
                          f"{len(self.y_N)} samples at {self.fs_Hz:g} Hz "
                          f"(from {self.raw_fs_Hz:g} Hz)",
                          f"band {self.band_Hz[0]:g}-{self.band_Hz[1]:g} Hz",
                          f"baseline {self.baseline_N:.3g} N")

    _repr_html_ = html_repr


def linear_detrend(x: np.ndarray, start: int = 0) -> np.ndarray:
    """Subtract the least-squares straight line (same as ``scipy.signal.detrend``, type
    'linear', without its LAPACK call).

    Parameters
    ----------
    x : ndarray
        The signal (1-D); the line is fitted to all of it.
    start : int
        Return the detrended signal from this sample on (the same values as
        ``linear_detrend(x)[start:]``, without computing the part before).

    Examples
    --------
    >>> import numpy as np
    >>> bool(np.allclose(linear_detrend(3.0 + 0.5 * np.arange(7.0)), 0.0))
    True
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 2:
        return (x - x.mean())[start:]
    k = np.arange(n, dtype=float) - (n - 1) / 2.0
    slope = dot(k, x) / dot(k, k)
    return x[start:] - x.mean() - slope * k[start:]


@functools.lru_cache(maxsize=32)
def _butter_sos(order: int, cutoff_Hz: float, fs_Hz: float) -> np.ndarray:
    return butter(order, cutoff_Hz, fs=fs_Hz, output="sos")


@functools.lru_cache(maxsize=32)
def _savgol_taps(window: int, order: int) -> np.ndarray:
    return savgol_coeffs(window, order)


def lowpass_sos(fs_Hz: float, settings: IdentificationSettings) -> np.ndarray | None:
    """Second-order sections of the Butterworth low-pass (None when disabled)."""
    if settings.lowpass_Hz is None:
        return None
    if settings.lowpass_Hz >= fs_Hz / 2:
        raise IdentificationError(
            f"lowpass_Hz = {settings.lowpass_Hz:g} is not below the Nyquist frequency "
            f"{fs_Hz / 2:g} Hz of the data; choose a lower cut-off or None")
    return _butter_sos(settings.butter_order, float(settings.lowpass_Hz), float(fs_Hz))


def smooth_and_lowpass(x: np.ndarray, fs_Hz: float,
                       settings: IdentificationSettings) -> np.ndarray:
    """Savitzky-Golay smoothing then Butterworth low-pass along the last axis.

    Parameters
    ----------
    x : ndarray
        Signal(s), samples along the last axis.
    fs_Hz : float
        Sampling rate.
    settings : IdentificationSettings
        ``savgol_window``, ``savgol_order``, ``lowpass_Hz``, ``butter_order``,
        ``zero_phase``.

    Returns
    -------
    ndarray
        Filtered signal(s), same shape.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(2000) / 2000.0
    >>> x = 0.3 + 2 * t                      # a straight line passes both filters
    >>> y = smooth_and_lowpass(x, 2000.0, IdentificationSettings())
    >>> bool(np.allclose(y, x, atol=1e-9))
    True
    """
    y = np.asarray(x, dtype=float)
    n = y.shape[-1]
    if settings.savgol_window is not None:
        if n < settings.savgol_window:
            raise IdentificationError(f"only {n} samples; the Savitzky-Golay window needs "
                                      f"{settings.savgol_window}")
        # same interior values as savgol_filter (the edges, where savgol_filter fits a
        # polynomial, are never analysed: they lie before the window or are trimmed)
        # the ends are padded by odd (point) reflection, which keeps straight lines exact
        taps = _savgol_taps(settings.savgol_window, settings.savgol_order)
        half = settings.savgol_window // 2
        first, last = y[..., :1], y[..., -1:]
        padded = np.concatenate([2 * first - y[..., half:0:-1], y,
                                 2 * last - y[..., -2:-half - 2:-1]], axis=-1)
        y = convolve1d(padded, taps, axis=-1, mode="constant")[..., half:half + n]
    sos = lowpass_sos(fs_Hz, settings)
    if sos is not None and settings.lowpass_Hz is not None:   # a cut-off gives the sos
        if settings.zero_phase:
            # pad by odd reflection long enough (3 / cut-off) for the start-up transient
            # of the filter to die out inside the padding: lines then pass exactly
            padlen = min(int(math.ceil(3.0 * fs_Hz / settings.lowpass_Hz)), n - 1)
            y = sosfiltfilt(sos, y, axis=-1, padlen=padlen)
        else:
            zi = sosfilt_zi(sos)
            zi = zi.reshape(zi.shape[:1] + (1,) * (y.ndim - 1) + zi.shape[1:]) \
                if y.ndim > 1 else zi
            first = y[..., :1] if y.ndim > 1 else y[0]
            y, _ = sosfilt(sos, y, axis=-1, zi=zi * first)
    return y


def window_indices(n_samples: int, fs_Hz: float, steady_s: float, chirp_s: float,
                   settings: IdentificationSettings) -> tuple[int, int]:
    """First and one-past-last raw sample index of the analysed window."""
    start = settings.window_start_s if settings.window_start_s is not None else steady_s
    end = settings.window_end_s if settings.window_end_s is not None else steady_s + chirp_s
    i0 = int(math.ceil(start * fs_Hz - 1e-9))
    i1 = min(n_samples, int(math.floor(end * fs_Hz + 1e-9)))
    return i0, i1


def delay_input(rE: np.ndarray, delay_s: float, fs_Hz: float) -> np.ndarray:
    """rE moved by ``delay_s`` (either sign) along the last axis, at the raw rate.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(0.0, 1.0, 50)
    >>> bool(np.allclose(delay_input(x, 0.0, 2000.0), x))
    True
    """
    if delay_s == 0.0:
        return np.asarray(rE, dtype=float)
    return fractional_delay(rE, delay_s * fs_Hz)


class TrialSignals:
    """Each repeat's filtered, windowed, decimated signals, computed once for all the fits
    of a session (a cache for :func:`preprocess_trials`).

    Every preprocessing step is linear, so the filtered average of a level's repeats is
    the average of each repeat filtered on its own (to rounding). Filtering each repeat
    once (its force once, its rE once per input delay) serves the level's fit without a
    delay, its refit with the estimated delay and the per-repeat fits of the scatter
    (:mod:`nmsid.analysis.scatter`): 135 filtered rows of a 45-trial session instead of
    150, in 30 batched calls instead of 75, and nothing filtered twice.

    Used only when the result is the same as filtering the average: the trials of a call
    have one length and the filters run on the whole trial with the input prefiltered
    (``filter_whole_trial`` and ``prefilter_input``, the defaults); otherwise
    :func:`preprocess_trials` filters as before. Holds references to the trials it
    filtered (rows are keyed by the trial object, checked by identity).

    Parameters
    ----------
    settings : IdentificationSettings
        The settings of every call that uses this cache.
    """

    def __init__(self, settings: IdentificationSettings):
        self.settings = settings
        self._rows: dict[tuple, tuple[object, np.ndarray]] = {}
        self._inputs: list[np.ndarray] = []     # the distinct rE records seen
        self._input_ids: dict[tuple[int, int], tuple[object, int]] = {}

    def _input_id(self, tr, n: int) -> int:
        """An index shared by trials whose first ``n`` rE samples are equal (the repeats
        of a protocol usually receive the same chirp: its rows are filtered once). Found
        once per trial and length: the level's fits and each repeat's own fit ask again."""
        known = self._input_ids.get((id(tr), n))
        if known is not None and known[0] is tr:
            return known[1]
        k = self._find_input(tr, n)
        self._input_ids[(id(tr), n)] = (tr, k)
        return k

    def _find_input(self, tr, n: int) -> int:
        rE = np.asarray(tr.rE, dtype=float)[:n]
        for k, seen in enumerate(self._inputs):
            if seen.shape == rE.shape and np.array_equal(seen, rE):
                return k
        self._inputs.append(rE)
        return len(self._inputs) - 1

    def applies(self, trials, settings: IdentificationSettings) -> bool:
        """Whether the rows of ``trials`` can be averaged for the same result."""
        return (settings is self.settings and settings.filter_whole_trial
                and settings.prefilter_input
                and len({len(tr.force_N) for tr in trials}) == 1
                and len({len(tr.rE) for tr in trials}) == 1)

    def rows(self, trials, delay_s: float, fs_Hz: float, span: tuple[int, int, int, int],
             n: int) -> tuple[np.ndarray, np.ndarray]:
        """(force rows, rE rows) of ``trials``: detrended / delayed, filtered from ``j0``,
        cut to ``[i0, i1)`` and taken every ``q``-th sample (``span = (j0, i0, i1, q)``)."""
        s = self.settings
        todo_f = [tr for tr in trials if self._get(("f", span, n), tr) is None]
        ids = [self._input_id(tr, n) for tr in trials]
        todo_r = [k for k in dict.fromkeys(ids) if ("r", span, n, delay_s, k) not in self._rows]
        if todo_f or todo_r:
            j0, i0, i1, q = span
            parts = []
            for tr in todo_f:       # only the part the filters see (from j0), detrended
                f = np.asarray(tr.force_N, dtype=float)       # by the line of all of it
                parts.append((linear_detrend(f, j0) if s.detrend else f[j0:])[:n - j0])
            if todo_r:
                parts.extend(delay_input(np.vstack([self._inputs[k] for k in todo_r]),
                                         delay_s, fs_Hz)[:, j0:])
            out = smooth_and_lowpass(np.vstack(parts), fs_Hz, s)
            out = np.ascontiguousarray(out[:, i0 - j0:i1 - j0:q])
            for k, tr in enumerate(todo_f):
                self._rows[("f", span, n, id(tr))] = (tr, out[k])
            for k, key in enumerate(todo_r):
                self._rows[("r", span, n, delay_s, key)] = (None, out[len(todo_f) + k])
        force = np.vstack([self._rows[("f", span, n, id(tr))][1] for tr in trials])
        rE = np.vstack([self._rows[("r", span, n, delay_s, k)][1] for k in ids])
        return force, rE

    def _get(self, key: tuple, trial) -> np.ndarray | None:
        found = self._rows.get(key + (id(trial),))
        return found[1] if found is not None and found[0] is trial else None


def preprocess_trials(trials, settings: IdentificationSettings | None = None, *,
                      input_delay_s: float | None = None,
                      cache: TrialSignals | None = None) -> LevelData:
    """Detrend, average, filter, window and decimate the repeats of one sE level.

    Parameters
    ----------
    trials : sequence of protocols.session_file.Trial
        Completed trials of the same sE with finite data (see
        ``analysis.identify.usable_trials``). Trials of different lengths are cut to the
        shortest (all start at stimulation onset).
    settings : IdentificationSettings, optional
    input_delay_s : float, optional
        Delay of the stimulation behind the rE record in s (either sign); default: the
        fixed delay of ``settings.input_timing`` (0 when it is ``"estimate"``: the
        estimate is made by :func:`nmsid.analysis.input_timing.fit_level`).
    cache : TrialSignals, optional
        Each repeat filtered once and kept for the session's other fits (the same result
        to rounding; used when :meth:`TrialSignals.applies`).

    Returns
    -------
    LevelData

    Raises
    ------
    IdentificationError
        No trials, different sampling rates, or a window too short to fit.
    """
    s = settings or IdentificationSettings()
    trials = list(trials)
    if not trials:
        raise IdentificationError("no trials to preprocess")
    first = trials[0]
    fs = float(first.fs_Hz)
    for tr in trials[1:]:
        if not math.isclose(tr.fs_Hz, fs, rel_tol=1e-9):
            raise IdentificationError(
                f"trials {first.name} and {tr.name} of sE={first.sE:g} were sampled at "
                f"different rates ({fs:g} and {tr.fs_Hz:g} Hz); cannot average them")
    n = min(len(tr.force_N) for tr in trials)
    if input_delay_s is None:
        input_delay_s = fixed_delay_s(s, fs)
    lead = slice(int(first.steady_s * fs / 2), int(first.steady_s * fs))
    baseline = float(np.mean([np.mean(tr.force_N[lead]) for tr in trials])) \
        if lead.stop > lead.start and n >= lead.stop else float("nan")
    i0, i1 = window_indices(n, fs, first.steady_s, first.chirp_s, s)
    trim = s.edge_trim_samples(fs)
    if s.filter_whole_trial:
        i1 = min(i1, n - trim)            # the end of the record is a filter edge
        i0 = max(i0, trim)                # so is its start, if the window starts there
    q = max(1, int(math.floor(fs / s.fit_fs_Hz + 1e-9))) if s.fit_fs_Hz else 1
    usable_len = (i1 - i0) - (0 if s.filter_whole_trial else 2 * trim)
    if usable_len // q < 60:
        raise IdentificationError(
            f"the window {i0 / fs:g}-{i1 / fs:g} s of sE={first.sE:g} holds "
            f"{max(usable_len, 0)} usable samples ({max(usable_len, 0) // q} at the fit rate); "
            f"the trials are {n / fs:g} s long - too short to fit")
    if cache is not None and cache.applies(trials, s):
        settle = max(0.5, 10.0 / s.lowpass_Hz if s.lowpass_Hz else 0.0)
        j0 = max(0, i0 - int(settle * fs))
        force_rows, rE_rows = cache.rows(trials, float(input_delay_s), fs, (j0, i0, i1, q), n)
        return _level_data(trials, force_rows.mean(axis=0), rE_rows.mean(axis=0), i0, q, fs,
                           baseline, float(input_delay_s))
    force = np.empty((len(trials), n))
    for k, tr in enumerate(trials):
        f = np.asarray(tr.force_N, dtype=float)
        force[k] = (linear_detrend(f) if s.detrend else f)[:n]
    rE = delay_input(np.vstack([np.asarray(tr.rE, dtype=float)[:n] for tr in trials]),
                     input_delay_s, fs)
    y = force.mean(axis=0)
    r = rE.mean(axis=0)
    if s.filter_whole_trial:
        # the filters' memory is far shorter than the lead-in: start them a settling time
        # (10 / lowpass_Hz, at least 0.5 s) before the window instead of at onset
        settle = max(0.5, 10.0 / s.lowpass_Hz if s.lowpass_Hz else 0.0)
        j0 = max(0, i0 - int(settle * fs))
        y, r = y[j0:], r[j0:]
        both = smooth_and_lowpass(np.vstack([y, r]), fs, s) if s.prefilter_input else None
        if both is not None:
            y, r = both[0], both[1]
        else:
            y = smooth_and_lowpass(y, fs, s)
        y, r = y[i0 - j0:i1 - j0], r[i0 - j0:i1 - j0]
    else:
        y, r = y[i0:i1], r[i0:i1]
        if s.prefilter_input:
            both = smooth_and_lowpass(np.vstack([y, r]), fs, s)
            y, r = both[0], both[1]
        else:
            y = smooth_and_lowpass(y, fs, s)
        y, r = y[trim:len(y) - trim], r[trim:len(r) - trim]   # both ends are filter edges
        i0 += trim
    return _level_data(trials, np.ascontiguousarray(y[::q]), np.ascontiguousarray(r[::q]), i0,
                       q, fs, baseline, float(input_delay_s))


def _level_data(trials, y: np.ndarray, r: np.ndarray, i0: int, q: int, fs: float,
                baseline: float, input_delay_s: float) -> LevelData:
    """The :class:`LevelData` of windowed, decimated signals starting at raw sample ``i0``."""
    first = trials[0]
    t = (i0 + q * np.arange(len(y))) / fs
    r_mean = float(np.mean(r))
    return LevelData(sE=float(first.sE), t_s=t, u=r - r_mean, y_N=y, fs_Hz=fs / q,
                     raw_fs_Hz=fs, n_trials=len(trials),
                     trial_names=[tr.name for tr in trials],
                     band_Hz=(float(first.chirp_f0_Hz), float(first.chirp_f1_Hz)),
                     rE_mean=r_mean, baseline_N=baseline, input_delay_s=input_delay_s)


def fixed_delay_s(settings: IdentificationSettings, fs_Hz: float) -> float:
    """The delay that ``settings.input_timing`` fixes (0 for ``"estimate"`` and ``"smooth"``,
    half a sample for ``"hold"``, the number itself for a calibrated delay).

    Examples
    --------
    >>> fixed_delay_s(IdentificationSettings(input_timing="hold"), 2000.0)
    0.00025
    >>> fixed_delay_s(IdentificationSettings(input_timing=-1e-4), 2000.0)
    -0.0001
    """
    timing = settings.input_timing
    if isinstance(timing, float):
        return timing
    if timing is InputTiming.HOLD:
        return 0.5 / fs_Hz
    return 0.0
