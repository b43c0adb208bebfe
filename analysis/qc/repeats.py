"""Response not explained by rE: what one repeat has that the other repeats do not share.

The repeats of one sE receive the same rE, so whatever the stimulation causes they share,
up to the physiology's repeat-to-repeat scatter of gain and timing. Per trial, after a
zero-phase low-pass (:attr:`QCSettings.lowpass_Hz`) and decimation to ~100 Hz:

1. the reference is the pointwise median of the level's repeats (three or more), or the
   other repeat (two);
2. the trial is regressed on [reference, d reference/dt, 1, t] (gain, a small time shift,
   offset and drift are shared physiology or sensor, not artefact) and the remainder is
   its *unshared component* u(t); the regression is refitted once without the flagged
   stretches so that an artefact cannot bend it;
3. the RMS of u in sliding windows (:attr:`QCSettings.window_s`) is compared with the
   level's typical (median) unshared RMS and with the level's response RMS; windows above
   both thresholds are flagged and merged into time spans.

A trial whose flagged stretches reach its end is tried against a baseline jump
(:func:`fit_jump`); anything else is a response not explained by rE. With two repeats the difference
is attributed with the neighbouring sE levels as an independent reference
(:func:`attribute_pair`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.qc.checks import runs
from analysis.qc.settings import QCSettings
from analysis.signal_kernels import butter, sosfiltfilt


@dataclass
class Deviation:
    """A stretch of one trial that the other repeats do not share.

    Attributes
    ----------
    start_s, stop_s : float
        The stretch, in s after stimulation onset.
    rms_N : float
        RMS of the unshared component there.
    ratio : float
        That RMS over the level's typical unshared RMS.
    step_N : float or None
        For a baseline jump, its height (N); None otherwise.
    step_at_s : float or None
        For a baseline jump, when it happened.
    """

    start_s: float
    stop_s: float
    rms_N: float
    ratio: float
    step_N: float | None = None
    step_at_s: float | None = None

    @property
    def is_jump(self) -> bool:
        return self.step_N is not None


def smoothed(force_N: np.ndarray, fs_Hz: float, settings: QCSettings) -> tuple[np.ndarray,
                                                                                float]:
    """Zero-phase low-pass then decimation; returns (signal, its rate in Hz)."""
    x = np.asarray(force_N, float)
    sos = butter(4, min(settings.lowpass_Hz, 0.4 * fs_Hz), fs=fs_Hz)
    y = sosfiltfilt(sos, x)
    step = max(1, int(fs_Hz // (5 * settings.lowpass_Hz)))
    return y[::step].copy(), fs_Hz / step


def _regress(s: np.ndarray, ref: np.ndarray, fs: float, keep: np.ndarray) -> np.ndarray:
    """s minus its least-absolute-deviation fit on [ref, ref', 1, t] over ``keep``.

    An L1 fit (iteratively reweighted least squares) follows the majority of the samples:
    a contraction or a jump over a minority of the trial cannot pull the gain, offset or
    drift that the rest defines, as it would pull a least-squares line.
    """
    t = np.arange(s.size) / fs
    X = np.column_stack([ref, np.gradient(ref) * fs, np.ones_like(t), t - t.mean()])[keep]
    y = s[keep]
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    floor = 1e-9 * max(float(np.std(y)), 1e-12)
    for _ in range(30):
        r = y - X @ beta
        sw = 1.0 / np.sqrt(np.maximum(np.abs(r), floor))
        new, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
        if np.allclose(new, beta, rtol=1e-6, atol=1e-9):
            beta = new
            break
        beta = new
    Xall = np.column_stack([ref, np.gradient(ref) * fs, np.ones_like(t), t - t.mean()])
    return s - Xall @ beta


def _align(s: np.ndarray, ref: np.ndarray, fs: float) -> np.ndarray:
    """s mapped onto ref's offset, drift and gain (its regression on [ref, 1, t] undone)."""
    t = np.arange(s.size) / fs
    X = np.column_stack([ref, np.ones_like(t), t - t.mean()])
    g, c, d = np.linalg.lstsq(X, s, rcond=None)[0]
    return (s - c - d * (t - t.mean())) / g if abs(g) > 1e-12 else s - c - d * (t - t.mean())


def _window_rms(u: np.ndarray, w: int) -> np.ndarray:
    w = max(3, min(w, u.size))
    c = np.convolve(u * u, np.ones(w) / w, mode="same")
    return np.sqrt(np.maximum(c, 0.0))


def unshared(signals: list[np.ndarray], fs: float, settings: QCSettings,
             references: list[np.ndarray] | None = None,
             level_scale: tuple[float, float] | None = None):
    """Unshared components and flagged windows of each signal.

    Parameters
    ----------
    signals : list of arrays (same length)
        The smoothed repeats of one level.
    fs : float
        Their rate.
    references : list of arrays, optional
        One reference per signal (default: the pointwise median of all signals, or the
        other signal when there are two).
    level_scale : (typical_rms, response_rms), optional
        Thresholds' scales; default from these signals.

    Returns
    -------
    u : list of arrays
    flags : list of bool arrays
    typical_rms, response_rms : float
    references : list of arrays
    limit : float
        The flagging threshold on the windowed RMS.
    """
    n = len(signals)
    S = np.vstack(signals)
    t = np.arange(S.shape[1]) / fs
    own = references is None
    if own and n < 2:
        raise ValueError("unshared needs two or more signals or explicit references")
    if own and n >= 3:
        # the median of the repeats after each is brought onto a common offset, drift and
        # gain (two passes: a line first, then the regression on the median itself)
        X = np.column_stack([np.ones_like(t), t - t.mean()])
        A = S - (X @ np.linalg.lstsq(X, S.T, rcond=None)[0]).T
        for _ in range(2):
            med = np.median(A, axis=0)
            A = np.vstack([_align(S[i], med, fs) for i in range(n)])
        references = [np.median(A, axis=0)] * n
    elif own:
        references = [S[1], S[0]]
    w = int(round(settings.window_s * fs))
    keep = [np.ones(S.shape[1], bool) for _ in range(n)]
    for _ in range(2):
        u = [_regress(S[i], references[i], fs, keep[i]) for i in range(n)]
        rms = [_window_rms(ui, w) for ui in u]
        if level_scale is None:
            typical = float(np.median(np.concatenate(rms)))
            ref0 = references[0]
            response = float(np.std(ref0[ref0.size // 3:]))
        else:
            typical, response = level_scale
        limit = max(settings.deviation_k * typical, settings.deviation_min_frac * response)
        flags = [r > limit for r in rms]
        new_keep = [~f if (~f).sum() > 0.5 * f.size else np.ones_like(f) for f in flags]
        if all(np.array_equal(a, b) for a, b in zip(new_keep, keep)):
            break
        keep = new_keep
    return u, flags, rms, typical, response, references, limit


def deviations(u: np.ndarray, flags: np.ndarray, rms: np.ndarray, fs: float, typical: float,
               settings: QCSettings) -> list[Deviation]:
    """Flagged windows of one trial as merged time spans (jumps: :func:`fit_jump`)."""
    w = int(round(settings.window_s * fs))
    spans = runs(flags)
    merged: list[list[int]] = []
    for a, b in spans:
        if merged and a - merged[-1][1] <= w:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    out = []
    n = u.size
    for a, b in merged:
        a0, b0 = max(0, a - w // 2), min(n, b + w // 2)
        seg_rms = float(np.sqrt(np.mean(u[a0:b0] ** 2)))
        dev = Deviation(a0 / fs, b0 / fs, seg_rms, seg_rms / typical if typical > 0 else
                        float("inf"))
        out.append(dev)
    return out


def attribute_pair(signals: list[np.ndarray], neighbour: np.ndarray | None, fs: float,
                   span: tuple[float, float], settings: QCSettings) -> int | None:
    """Which of two repeats holds a difference: index 0 or 1, or None if undecidable.

    Each repeat is regressed on the neighbouring levels' response (a reference that
    neither repeat contributes to); the repeat whose remainder inside ``span`` is at least
    :attr:`QCSettings.attribute_ratio` times the other's holds the difference.
    """
    if neighbour is None:
        return None
    a, b = int(span[0] * fs), int(span[1] * fs)
    keep = np.ones(signals[0].size, bool)
    keep[max(0, a):b] = False
    if keep.sum() < 10:
        return None
    m = min(neighbour.size, signals[0].size, signals[1].size)
    keep = keep[:m]
    e = []
    for s in signals:
        u = _regress(s[:m], neighbour[:m], fs, keep)
        e.append(float(np.sqrt(np.mean(u[a:b] ** 2))))
    if e[0] >= settings.attribute_ratio * e[1]:
        return 0
    if e[1] >= settings.attribute_ratio * e[0]:
        return 1
    return None


def fit_jump(s: np.ndarray, ref: np.ndarray, fs: float, limit: float,
             settings: QCSettings) -> tuple[float, float] | None:
    """A baseline jump that explains all of a trial's difference from its repeats.

    The trial is regressed on [ref, ref', 1, t, H(t - T)] for every T on a grid (every
    two samples); with the best T, the remainder must stay below ``limit`` in every window
    away from the jump itself. Returns (height in N, T in s) or None.
    """
    n = s.size
    t = np.arange(n) / fs
    base = np.column_stack([ref, np.gradient(ref) * fs, np.ones(n), t - t.mean()])
    w = int(round(settings.window_s * fs))
    best = None
    for k in range(w, n - w, 2):
        X = np.column_stack([base, (np.arange(n) >= k).astype(float)])
        beta, res, *_ = np.linalg.lstsq(X, s, rcond=None)
        sse = float(res[0]) if res.size else float(np.sum((s - X @ beta) ** 2))
        if best is None or sse < best[0]:
            best = (sse, k, beta)
    if best is None:
        return None
    _, k, beta = best
    X = np.column_stack([base, (np.arange(n) >= k).astype(float)])
    rms = _window_rms(s - X @ beta, w)
    away = np.ones(n, bool)
    away[max(0, k - w):k + w] = False
    if np.all(rms[away] <= limit):
        return float(beta[-1]), k / fs
    return None
