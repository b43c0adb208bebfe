"""Checks of one trial on its own: non-finite, stalled and clipped stretches, spikes, noise.

Each check returns :class:`Finding` s with the samples it concerns; :mod:`nmsid.analysis.qc.decide`
turns them into a decision. Nothing here knows the model or the other repeats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt


@dataclass
class Finding:
    """One artefact in one trial.

    Attributes
    ----------
    kind : str
        ``nonfinite``, ``stalled``, ``clipping``, ``spike``, ``lead_in_noise``,
        ``unexplained``, ``baseline_jump``, ``repeats_disagree``.
    spans : list of (int, int)
        Sample ranges [start, stop) concerned.
    detail : str
        A sentence for the table.
    repairable : bool
        True when bridging the spans is honest (short, isolated).
    """

    kind: str
    spans: list[tuple[int, int]]
    detail: str
    repairable: bool = False


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of True in a boolean array."""
    mask = np.asarray(mask, bool)
    if not mask.any():      # the usual case (no outlier, no repeated value): no edge search
        return []
    m = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def median_of_finite(x: np.ndarray, scratch: bool = False) -> float:
    """``np.median(x)`` of a non-empty array with no NaN, exactly, at a third of the cost.

    ``np.median`` partitions at three places (both middles and the end, for its NaN
    check); the median is the same two order statistics found with one partition at the
    upper middle and a maximum over the half below it, averaged the way ``np.mean`` does
    (``(0 + a + b) / 2``): the same numbers, so the same result bit for bit.
    ``scratch``: ``x`` is a temporary the caller no longer needs (partitioned in place).
    """
    x = np.asarray(x, float)
    n = x.size
    part = x if scratch and x.flags.writeable else x.copy()
    h = n // 2
    part.partition(h)
    upper = part[h]
    # np.mean's sum starts from +0.0 (so a median of -0.0 is 0.0), then divides
    if n % 2:
        return float((0.0 + upper) / 1.0)
    return float((0.0 + part[:h].max() + upper) / 2.0)


def quantile_of_finite(x: np.ndarray, q: float, scratch: bool = False) -> float:
    """``np.quantile(x, q)`` (method "linear") of a non-empty array with no NaN, for
    ``0 <= q <= 1``, exactly, from one partition (``np.quantile`` partitions at four
    places: the first, the last and the two neighbours of its index).

    The same steps as numpy's: index ``(n - 1) q``, its floor and the next order
    statistic, and numpy's interpolation (``a + (b - a) g`` below ``g = 0.5``, else
    ``b - (b - a)(1 - g)``). (Of equal values of opposite sign, +0 and -0, either may be
    returned, as from any partition.) ``scratch``: partition ``x`` in place.
    """
    x = np.asarray(x, float)
    n = x.size
    virtual = (n - 1) * np.float64(q)
    part = x if scratch and x.flags.writeable else x.copy()
    if virtual >= n - 1:                      # numpy takes the largest value
        return float(part.max())
    lo = int(np.floor(virtual))
    part.partition(lo + 1)
    b = part[lo + 1]
    a = part[:lo + 1].max()
    g = float(virtual - lo)
    d = b - a
    return float(a + d * g if g < 0.5 else b - d * (1 - g))


def robust_sd(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (the SD for Gaussian data)."""
    x = np.asarray(x, float)
    finite = np.isfinite(x)
    if not finite.all():
        x = x[finite]
    if x.size == 0:
        return float("nan")
    dev = np.abs(x - median_of_finite(x))
    return float(1.4826 * median_of_finite(dev, scratch=True))


def hf_noise_sd(x: np.ndarray, dx: np.ndarray | None = None) -> float:
    """Robust SD of white noise from the second difference (blind to drift and response).

    For white noise of SD s the second difference has SD s sqrt(6); a smooth response
    (<= 10 Hz at 2 kHz) and 50 Hz pick-up contribute < 2 % of their amplitude to it.
    ``dx``: ``np.diff(x)`` when the caller has it already.
    """
    return noise_sd_of_second_difference(
        np.diff(np.diff(np.asarray(x, float)) if dx is None else dx))


def noise_sd_of_second_difference(d2: np.ndarray) -> float:
    """:func:`hf_noise_sd` from the second difference ``d2`` of the signal (a caller that
    has it already, or a slice of it for a part of the signal)."""
    return robust_sd(d2) / np.sqrt(6.0)


def quantum(x: np.ndarray, dx: np.ndarray | None = None) -> float:
    """The recording's resolution: the smallest step between samples (0 if none).

    ``dx``: ``np.diff(x)`` when the caller has it already."""
    d = np.abs(np.diff(np.asarray(x, float)) if dx is None else dx)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        return 0.0
    return quantile_of_finite(d, 0.001, scratch=True)


def nonfinite(x: np.ndarray, fs_Hz: float, max_s: float, label: str) -> list[Finding]:
    """NaN or Inf samples; short runs are bridgeable."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return []
    out = []
    for a, b in runs(bad):
        short = (b - a) / fs_Hz <= max_s and a > 0 and b < x.size
        out.append(Finding("nonfinite", [(a, b)],
                           f"{b - a} non-finite sample(s) in {label}", repairable=short))
    return out


def flat_runs(x: np.ndarray, fs_Hz: float, stall_min_s: float, clip_min_s: float,
              noise_sd: float, dx: np.ndarray | None = None) -> list[Finding]:
    """Identical consecutive samples: clipping at the trial's extremes, else a stall.

    Skipped when the noise is below half the recording's resolution: such a recording
    may repeat values honestly. ``dx``: ``np.diff(x)`` when the caller has it already.
    """
    dx = np.diff(x) if dx is None else dx
    q = quantum(x, dx)
    if not np.isfinite(noise_sd) or noise_sd < 0.5 * q:
        return []
    # a run of k equal samples is k-1 True in np.diff(x) == 0; widen to include its first
    # sample: the run [a, b) of True at [a + 1, b + 1) in [False] + (dx == 0)
    same = dx == 0
    out: list[Finding] = []
    if not same.any():
        return out
    edges = np.flatnonzero(np.diff(np.concatenate([[False], same, [False]]).astype(np.int8)))
    a_all, b_all = edges[::2], edges[1::2] + 1
    # only runs long enough to be reported (a quantised sensor repeats values in hundreds
    # of short runs a trial): the same test as below, on all runs at once
    long = (b_all - a_all) / fs_Hz >= min(clip_min_s, stall_min_s)
    if not long.any():
        return out
    hi, lo = np.nanmax(x), np.nanmin(x)
    for a, b in zip(a_all[long].tolist(), b_all[long].tolist(), strict=True):
        n = b - a
        value = x[a]
        at_edge = value == hi or value == lo
        if at_edge and n / fs_Hz >= clip_min_s:
            out.append(Finding("clipping", [(a, b)],
                               f"flat at the trial's {'maximum' if value == hi else 'minimum'}"
                               f" {value:.4g} N for {1000 * n / fs_Hz:.0f} ms (sensor or A/D "
                               "range)"))
        elif n / fs_Hz >= stall_min_s:
            out.append(Finding("stalled", [(a, b)],
                               f"{n} identical samples ({1000 * n / fs_Hz:.0f} ms): stream "
                               "stalled"))
    return out


def spike_lowpass_sos(fs_Hz: float, highpass_Hz: float) -> np.ndarray:
    """The low-pass whose remainder :func:`spikes` searches (order 4 at ``highpass_Hz``,
    at most 0.4 ``fs_Hz``)."""
    return butter(4, min(highpass_Hz, 0.4 * fs_Hz), fs=fs_Hz, output="sos")


def spikes(x: np.ndarray, fs_Hz: float, highpass_Hz: float, k: float,
           max_s: float, lowpassed: np.ndarray | None = None) -> list[Finding]:
    """Isolated outliers (cable knocks, A/D glitches) in the signal's high-pass part.

    Above ``highpass_Hz`` the muscle contributes nothing (the response lies below ~20 Hz,
    mains below ~200 Hz are removed too when ``highpass_Hz`` exceeds them), so what is left
    is sensor noise, whose robust SD sets the threshold, and broadband glitches. A spike's
    extent is taken at half its peak (the filter's ringing around it is not data).
    ``lowpassed``: ``x`` through :func:`spike_lowpass_sos` (zero-phase) when the caller
    filtered it already, with other trials in one batch.
    """
    fc = min(highpass_Hz, 0.4 * fs_Hz)
    if x.size < int(fs_Hz / fc) * 8:
        return []
    if lowpassed is None:
        lowpassed = sosfiltfilt(spike_lowpass_sos(fs_Hz, highpass_Hz), x)
    hp = x - lowpassed
    sd = robust_sd(hp)
    if not np.isfinite(sd) or sd == 0:
        return []
    out = []
    for a, b in runs(np.abs(hp) > k * sd):
        seg = np.abs(hp[a:b])
        core = np.flatnonzero(seg > 0.5 * seg.max())
        a1, b1 = a + int(core[0]), a + int(core[-1]) + 1
        if (b1 - a1) / fs_Hz > max_s or a1 < 3 or b1 + 3 > x.size:
            continue
        # a spike leaves and returns to the same level; a step or a kink does not
        left, right = x[a1 - 3], x[b1 + 2]
        line = np.interp(np.arange(a1, b1), [a1 - 3, b1 + 2], [left, right])
        away = float(np.max(np.abs(x[a1:b1] - line)))
        if away > k * sd and abs(right - left) < 0.5 * away:
            out.append(Finding("spike", [(a1, b1)], f"spike of {away:.3g} N",
                               repairable=True))
    return out


def bridge(x: np.ndarray, spans: list[tuple[int, int]], margin: int = 1) -> np.ndarray:
    """Linear interpolation across each span (with ``margin`` samples either side)."""
    y = np.array(x, dtype=float, copy=True)
    for a, b in spans:
        a0, b0 = max(a - margin, 0), min(b + margin, y.size)
        left, right = a0 - 1, b0
        if left < 0 and right >= y.size:
            continue
        if left < 0:
            y[a0:b0] = y[right]
        elif right >= y.size:
            y[a0:b0] = y[left]
        else:
            y[a0:b0] = np.interp(np.arange(a0, b0), [left, right], [y[left], y[right]])
    return y
