"""Response not explained by rE: what one repeat has that the other repeats do not share.

The repeats of one sE receive the same rE, so whatever the stimulation causes they share,
up to the physiology's repeat-to-repeat scatter of gain and timing. Per trial, after a
zero-phase low-pass (:attr:`QCSettings.lowpass_Hz`) and decimation to ~100 Hz:

1. every repeat is compared with every other one (its *partner*);
2. the trial is regressed on its partner through a short two-sided FIR filter
   (:attr:`QCSettings.shared_filter_s`), an offset and a drift (gain, timing and small
   changes of the dynamics are shared physiology, offset and drift the sensor's; none is
   artefact) and the remainder is its *unshared component* u(t); the regression is
   refitted once without the flagged stretches so that an artefact cannot bend it;
3. the RMS of u in sliding windows (:attr:`QCSettings.window_s`), the smallest over the
   partners (a repeat differs where it differs from all the others), is compared with
   the level's typical (median) unshared RMS and with the level's response RMS; windows
   above both thresholds are flagged and merged into time spans.

A trial whose flagged stretches reach its end is tried against a baseline jump
(:func:`fit_jump`); anything else is a response not explained by rE. With two repeats the difference
is attributed with the neighbouring sE levels as an independent reference
(:func:`attribute_pair`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from nmsid.analysis.qc.checks import median_of_finite, runs
from nmsid.analysis.qc.settings import QCSettings


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
    """Zero-phase low-pass then decimation; returns (signal, its rate in Hz).

    ``force_N`` may hold several signals (rows, one length): each is filtered on its own,
    in one call."""
    x = np.asarray(force_N, float)
    sos = butter(4, min(settings.lowpass_Hz, 0.4 * fs_Hz), fs=fs_Hz, output="sos")
    y = sosfiltfilt(sos, x)
    step = max(1, int(fs_Hz // (5 * settings.lowpass_Hz)))
    return y[..., ::step].copy(), fs_Hz / step


TAP_S = 0.02
"""Spacing of the shared filter's taps: 50 Hz, above twice the comparison's 20 Hz
bandwidth (:attr:`QCSettings.lowpass_Hz`), so the taps lose nothing the signals hold."""


def _filter_lags(fs: float, half_s: float) -> tuple[int, int]:
    """(tap spacing, largest lag) in samples of the shared filter; lag 0: no filter."""
    step = max(1, int(round(TAP_S * fs)))
    lags = int(round(half_s * fs)) // step * step
    return step, (lags if lags >= step else 0)


def shared_regressors(ref: np.ndarray, fs: float, half_s: float) -> np.ndarray:
    """Columns of what a trial may share with its reference: the reference delayed and
    advanced by every tap (:data:`TAP_S`) up to ``half_s`` (a two-sided FIR filter; edges
    held), or with ``half_s`` below one tap the reference and its derivative (gain and a
    small time shift); then an offset and a drift."""
    n = ref.size
    t = np.arange(n) / fs
    step, lags = _filter_lags(fs, half_s)
    if not lags:
        cols = [ref, np.gradient(ref) * fs]
    else:
        padded = np.concatenate([np.full(lags, ref[0]), ref, np.full(lags, ref[-1])])
        cols = [padded[lags + k:lags + k + n] for k in range(-lags, lags + 1, step)]
    return np.column_stack(cols + [np.ones(n), t - t.mean()])


def _weighted_solve(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least squares by the normal equations (fast for the few dozen columns
    here), falling back on an SVD solution when they are singular."""
    Xw = X * w[:, None]
    try:
        return np.linalg.solve(Xw.T @ X, Xw.T @ y)
    except np.linalg.LinAlgError:
        sw = np.sqrt(w)
        return np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]


class _Reference:
    """One repeat as the reference of the others: its :func:`shared_regressors`, and per
    set of samples fitted the rows and the unweighted normal matrix every regression on it
    starts from (the same arrays :func:`_weighted_solve` would build, built once)."""

    def __init__(self, regressors: np.ndarray):
        self.regressors = regressors
        self._start: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def start(self, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, X * 1, (X * 1).T @ X) of the rows ``inside``."""
        key = inside.tobytes()
        if key not in self._start:
            X = self.regressors[inside]
            Xw = X * np.ones(X.shape[0])[:, None]     # a copy, as _weighted_solve's
            self._start[key] = (X, Xw, Xw.T @ X)
        return self._start[key]


def _least_squares_start(X: np.ndarray, Xw: np.ndarray, G: np.ndarray,
                         y: np.ndarray) -> np.ndarray:
    """``_weighted_solve(X, y, ones)`` from its normal matrix ``G`` built already."""
    try:
        return np.linalg.solve(G, Xw.T @ y)
    except np.linalg.LinAlgError:
        return _weighted_solve(X, y, np.ones(y.size))


def _regress(s: np.ndarray, ref: np.ndarray, fs: float, keep: np.ndarray,
             half_s: float = 0.0, reference: _Reference | None = None) -> np.ndarray:
    """s minus its least-absolute-deviation fit on :func:`shared_regressors` over ``keep``.

    An L1 fit (iteratively reweighted least squares) follows the majority of the samples:
    a contraction or a jump over a minority of the trial cannot pull the gain, filter,
    offset or drift that the rest defines, as it would pull a least-squares line.
    ``reference``: ``ref``'s regressors and normal matrices when the caller holds them
    (one reference serves every other repeat of its level).
    """
    if reference is None:
        reference = _Reference(shared_regressors(ref, fs, half_s))
    Xall = reference.regressors
    edge = filter_edge(ref.size, fs, half_s)
    inside = keep.copy()
    inside[:edge] = False
    inside[ref.size - edge:] = False
    if inside.sum() < 3 * Xall.shape[1]:
        inside = keep
    X, Xw, G = reference.start(inside)
    y = s[inside]
    beta = _least_squares_start(X, Xw, G, y)           # least squares to start from
    floor = 1e-9 * max(float(np.std(y)), 1e-12)
    r = y - X @ beta
    l1 = float(np.sum(np.abs(r)))
    for _ in range(30):   # stop once the sum of |residuals| improves by < 0.1 %
        beta = _weighted_solve(X, y, 1.0 / np.maximum(np.abs(r), floor))
        r = y - X @ beta
        l1, before = float(np.sum(np.abs(r))), l1
        if before - l1 < 1e-3 * l1:
            break
    u = s - Xall @ beta
    if edge:   # the held edges are not the reference: no evidence there either way
        u[:edge] = 0.0
        u[u.size - edge:] = 0.0
    return u


def filter_edge(n: int, fs: float, half_s: float) -> int:
    """Samples at each end of a record where the shared filter reaches past it (its
    lagged references are held edges there, not the reference): 0 without the filter."""
    lags = _filter_lags(fs, half_s)[1]
    return lags if 2 * lags < n else 0


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))``, exactly, by :func:`checks.median_of_finite` when ``x`` is
    finite."""
    return median_of_finite(x) if x.size and np.isfinite(x).all() else float(np.median(x))


def _window_rms(u: np.ndarray, w: int) -> np.ndarray:
    w = max(3, min(w, u.size))
    c = np.convolve(u * u, np.ones(w) / w, mode="same")
    return np.sqrt(np.maximum(c, 0.0))


def unshared(signals: list[np.ndarray], fs: float, settings: QCSettings):
    """Unshared components and flagged windows of each repeat of one level.

    Every repeat is compared with every other (:func:`_regress`: the other through the
    shared filter, plus offset and drift). A repeat differs *where it differs from all
    the others*: its windowed RMS is the pointwise minimum over its partners. So a clean
    repeat is not blamed for an artefact in another, and no pointwise median (which
    switches between repeats whose dynamics differ) stands in as a reference. With two
    repeats both show the difference; :func:`attribute_pair` decides.

    Parameters
    ----------
    signals : list of arrays (same length, two or more)
        The smoothed repeats of one level.
    fs : float
        Their rate.

    Returns
    -------
    u : list of arrays
        Each repeat's remainder against its closest partner.
    flags : list of bool arrays
    rms : list of arrays
    typical_rms, response_rms : float
    references : list of arrays
        Each repeat's closest partner (the other repeat that explains it best).
    limit : float
        The flagging threshold on the windowed RMS.
    """
    n = len(signals)
    if n < 2:
        raise ValueError("unshared needs two or more signals")
    S = np.vstack(signals)
    w = int(round(settings.window_s * fs))
    keep = [np.ones(S.shape[1], bool) for _ in range(n)]
    response = float(np.std(np.median(S, axis=0)[S.shape[1] // 3:]))
    # each repeat's regressors built once, as the reference of every other repeat; a
    # regression whose trial keeps the same samples in the second pass is the same
    references = [_Reference(shared_regressors(S[j], fs, settings.shared_filter_s))
                  for j in range(n)]
    done: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for _ in range(2):
        u, rms, partner = [], [], []
        for i in range(n):
            pairs = []
            for j in range(n):
                if j != i:
                    before = done.get((i, j))
                    if before is not None and np.array_equal(before[0], keep[i]):
                        uij, rij = before[1], before[2]
                    else:
                        uij = _regress(S[i], S[j], fs, keep[i], settings.shared_filter_s,
                                       references[j])
                        rij = _window_rms(uij, w)
                        done[(i, j)] = (keep[i], uij, rij)
                    pairs.append((uij, rij, j))
            best = min(pairs, key=lambda p: _median(p[1]))
            u.append(best[0])
            rms.append(np.min(np.vstack([p[1] for p in pairs]), axis=0))
            partner.append(best[2])
        typical = float(np.median(np.concatenate(rms)))
        limit = max(settings.deviation_k * typical, settings.deviation_min_frac * response)
        flags = [r > limit for r in rms]
        new_keep = [~f if (~f).sum() > 0.5 * f.size else np.ones_like(f) for f in flags]
        if all(np.array_equal(a, b) for a, b in zip(new_keep, keep, strict=True)):
            break
        keep = new_keep
    return u, flags, rms, typical, response, [S[j] for j in partner], limit


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
        u = _regress(s[:m], neighbour[:m], fs, keep, settings.shared_filter_s)
        e.append(float(np.sqrt(np.mean(u[a:b] ** 2))))
    if e[0] >= settings.attribute_ratio * e[1]:
        return 0
    if e[1] >= settings.attribute_ratio * e[0]:
        return 1
    return None


def fit_jump(s: np.ndarray, ref: np.ndarray, fs: float, limit: float,
             settings: QCSettings) -> tuple[float, float] | None:
    """A baseline jump that explains all of a trial's difference from its repeats.

    The trial is regressed on :func:`shared_regressors` and H(t - T) for every T on a grid
    (every two samples); with the best T, the remainder must stay below ``limit`` in every window
    away from the jump itself. Returns (height in N, T in s) or None.
    """
    n = s.size
    base = shared_regressors(ref, fs, settings.shared_filter_s)
    w = int(round(settings.window_s * fs))
    if n - w <= w:
        return None
    # least squares with a step at every k at once: with Q an orthonormal basis of the
    # base columns and r the base fit's residual, a step at k lowers the squared error by
    # (sum_{i>=k} r_i)^2 / ((n - k) - |sum_{i>=k} Q_i|^2)
    Q, _ = np.linalg.qr(base)
    r = s - Q @ (Q.T @ s)
    tail_r = np.cumsum(r[::-1])[::-1]
    tail_q = np.cumsum(Q[::-1], axis=0)[::-1]
    ks = np.arange(w, n - w, 2)
    denom = (n - ks) - np.sum(tail_q[ks] ** 2, axis=1)
    gain = np.where(denom > 1e-9, tail_r[ks] ** 2 / np.maximum(denom, 1e-9), -np.inf)
    k = int(ks[int(np.argmax(gain))])
    X = np.column_stack([base, (np.arange(n) >= k).astype(float)])
    beta = np.linalg.lstsq(X, s, rcond=None)[0]
    rms = _window_rms(s - X @ beta, w)
    away = np.ones(n, bool)
    away[max(0, k - w):k + w] = False
    edge = filter_edge(n, fs, settings.shared_filter_s)
    if edge:
        away[:edge] = False
        away[n - edge:] = False
    if np.all(rms[away] <= limit):
        return float(beta[-1]), k / fs
    return None
