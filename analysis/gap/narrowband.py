"""Narrow-band components of a held-out residual: instrument lines and oscillations.

The mean periodogram of the held-out residual is searched for peaks above a running-median
background. A peak as narrow as the frequency resolution, at the same frequency in every
trial, is an instrument line (mains, the stimulator's carrier or their aliases): listed,
not counted. A wider peak (a physiological oscillation, e.g. tremor at 8-12 Hz) whose power
beyond the background is material is an unexplained component (``analysis.gap.verdict``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def narrow_band(resid: np.ndarray, reference: np.ndarray, noise: np.ndarray | None,
                fs_Hz: float, f_max_Hz: float, *, f_min_Hz: float = 1.0,
                peak_ratio: float = 2.0,
                line_width_Hz: float = 0.45, min_beyond_noise_pct: float = 0.1) -> list[dict]:
    """Narrow-band components of a residual (see module): frequency, width, kind, size.

    Parameters
    ----------
    resid : (n_trials, n) ndarray
    reference : (n_trials, n) ndarray
    noise : (n_trials, m) ndarray or None
        Lead-in noise rows: is the component there at rest too?
    fs_Hz, f_max_Hz : float
        Sampling rate and the top of the analysed band.

    Returns
    -------
    list of dict
        ``f_Hz``, ``width_Hz``, ``kind`` (``line`` or ``band``), ``beyond_noise_pct``,
        ``trial_spread_Hz`` (interquartile range of the trials' peak frequencies), ``at_rest``
        (its power in the lead-in relative to the lead-in background, or None),
        ``significant`` (a material band).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(1000) / 100.0
    >>> r = rng.normal(0, 0.1, (20, 1000)) + 0.2 * np.sin(2 * np.pi * 5.0 * t)
    >>> c = narrow_band(r, np.ones((20, 1000)), None, 100.0, 25.0)
    >>> [(round(x["f_Hz"], 1), x["kind"]) for x in c]
    [(5.0, 'line')]
    """
    n = resid.shape[1]
    if resid.shape[0] == 0 or n < 64:
        return []
    win = np.hanning(n)
    norm = float(np.sum(win ** 2))
    P = np.mean(np.abs(np.fft.rfft(resid * win, axis=1)) ** 2, axis=0) / norm
    f = np.fft.rfftfreq(n, 1.0 / fs_Hz)
    df = f[1]
    use = (f >= f_min_Hz) & (f <= f_max_Hz)
    # background: the log-spectrum's smooth trend (cubic over the band) plus a running
    # 35th percentile of what is left over +-4 Hz, so that a peak a few Hz wide (tremor)
    # does not raise its own background, and the filter's roll-off is no peak
    L = np.log(np.maximum(P, 1e-300))
    fu = f[use]
    if use.sum() < 16:
        return []
    coef = np.polyfit(fu, L[use], 3)
    trend = np.polyval(coef, f)
    R = L - trend
    half = max(3, int(round(4.0 / df)))
    pad = np.pad(R, half, mode="reflect")
    bgR = np.array([np.percentile(pad[i:i + 2 * half + 1], 35) for i in range(len(P))])
    bg = np.exp(trend + bgR)
    hot = use & (P > peak_ratio * bg)
    ref_ms = float(np.mean(reference ** 2))
    # groups of hot bins; gaps under 0.5 Hz joined (one component may dip in places)
    idx = np.flatnonzero(hot)
    groups: list[list[int]] = []
    for k in idx:
        if groups and (k - groups[-1][-1]) * df < 0.5:
            groups[-1].append(int(k))
        else:
            groups.append([int(k)])
    Pt = np.abs(np.fft.rfft(resid * win, axis=1)) ** 2          # per trial
    out: list[dict[str, Any]] = []
    for g in groups:
        i, j = g[0], g[-1]
        sl = slice(i, j + 1)
        ex = np.maximum(P[sl] - bg[sl], 0.0)
        if ex.sum() <= 0:
            continue
        kp = i + int(np.argmax(ex))
        top = P[kp] - bg[kp]
        a = b = kp
        while a - 1 >= i and P[a - 1] - bg[a - 1] >= 0.5 * top:
            a -= 1
        while b + 1 <= j and P[b + 1] - bg[b + 1] >= 0.5 * top:
            b += 1
        width = float((b - a + 1) * df)                     # half-power width
        fc = float(np.sum(f[sl] * ex) / ex.sum())
        if width > fc / 2:      # not an oscillation: a broad low-frequency excess
            continue
        # a line sits at the same frequency in every trial; an oscillation wanders
        lo_k, hi_k = max(i - 3, 1), min(j + 4, len(P))
        peaks = f[lo_k + np.argmax(Pt[:, lo_k:hi_k], axis=1)]
        spread = float(np.subtract(*np.percentile(peaks, [75, 25])))
        if width <= line_width_Hz and spread <= 2 * df:
            kind = "line"
        elif width < 2.5 * df:  # a bin or two, wandering: neither a line nor an oscillation
            continue
        else:
            kind = "band"
        # power per bin -> mean square: Parseval with the window's normalisation, 2 sides
        ms = 2.0 * float(ex.sum()) / n
        beyond = 100.0 * math.sqrt(ms / ref_ms) if ref_ms > 0 else float("nan")
        at_rest = None
        if noise is not None and noise.shape[1] >= 32:
            m = noise.shape[1]
            wn = np.hanning(m)
            Pn = np.mean(np.abs(np.fft.rfft(noise * wn, axis=1)) ** 2, axis=0)
            fn = np.fft.rfftfreq(m, 1.0 / fs_Hz)
            near = (fn >= f[a] - df) & (fn <= f[b] + df)
            away = (fn > 0.5) & (np.abs(fn - fc) > 3.0) & (np.abs(fn - fc) < 8.0)
            if near.any() and away.any():
                at_rest = float(np.mean(Pn[near]) / np.median(Pn[away]))
        out.append({"f_Hz": fc, "width_Hz": width, "kind": kind, "beyond_noise_pct": beyond,
                    "trial_spread_Hz": spread, "at_rest": at_rest,
                    "significant": bool(kind == "band" and beyond >= min_beyond_noise_pct
                                        and top >= 3 * bg[kp])})
    out.sort(key=lambda c: -c["beyond_noise_pct"])
    return out[:6]
