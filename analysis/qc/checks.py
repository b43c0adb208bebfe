"""Checks of one trial on its own: non-finite, stalled and clipped stretches, spikes, noise.

Each check returns :class:`Finding` s with the samples it concerns; :mod:`nmsid.analysis.qc.decide`
turns them into a decision. Nothing here knows the model or the other repeats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from nmsid.analysis.signal_kernels import butter, sosfiltfilt


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
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def robust_sd(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (the SD for Gaussian data)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def hf_noise_sd(x: np.ndarray) -> float:
    """Robust SD of white noise from the second difference (blind to drift and response).

    For white noise of SD s the second difference has SD s sqrt(6); a smooth response
    (<= 10 Hz at 2 kHz) and 50 Hz pick-up contribute < 2 % of their amplitude to it.
    """
    d2 = np.diff(np.asarray(x, float), 2)
    return robust_sd(d2) / np.sqrt(6.0)


def quantum(x: np.ndarray) -> float:
    """The recording's resolution: the smallest step between samples (0 if none)."""
    d = np.abs(np.diff(np.asarray(x, float)))
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        return 0.0
    return float(np.quantile(d, 0.001))


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
              noise_sd: float) -> list[Finding]:
    """Identical consecutive samples: clipping at the trial's extremes, else a stall.

    Skipped when the noise is below half the recording's resolution: such a recording
    may repeat values honestly.
    """
    q = quantum(x)
    if not np.isfinite(noise_sd) or noise_sd < 0.5 * q:
        return []
    same = np.concatenate([[False], np.diff(x) == 0])
    # a run of k equal samples is k-1 True in `same`; widen to include its first sample
    out = []
    hi, lo = np.nanmax(x), np.nanmin(x)
    for a, b in runs(same):
        a -= 1
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
    return butter(4, min(highpass_Hz, 0.4 * fs_Hz), fs=fs_Hz)


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
