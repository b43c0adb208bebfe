"""Stability margins of a loop from its frequency response.

The quantities are those of python-control's ``margin`` / ``stability_margins``: the gain
margin at the phase crossover (phase -180 deg), the phase margin at the gain crossover
(|L| = 1) and the delay margin ``PM / wc``. Computed on a dense logarithmic grid, each
crossing refined by bisection on the continuous response.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop."""

    gain_margin: float
    """Factor the loop gain may grow by before instability (inf: the phase never reaches
    -180 deg)."""
    phase_margin_deg: float
    crossover_rad_s: float
    """Gain crossover (nan if |L| never crosses 1)."""
    phase_crossover_rad_s: float
    delay_margin_s: float
    """Extra loop delay the loop tolerates, PM / wc (inf without a gain crossover)."""

    def to_dict(self) -> dict:
        def num(x):
            return None if not math.isfinite(x) else round(float(x), 6)
        return {"gain_margin": num(self.gain_margin),
                "gain_margin_dB": num(20 * math.log10(self.gain_margin))
                if math.isfinite(self.gain_margin) and self.gain_margin > 0 else None,
                "phase_margin_deg": num(self.phase_margin_deg),
                "crossover_rad_s": num(self.crossover_rad_s),
                "phase_crossover_rad_s": num(self.phase_crossover_rad_s),
                "delay_margin_s": num(self.delay_margin_s)}


def _bisect(f: Callable[[float], float], a: float, b: float, n: int = 60) -> float:
    fa = f(a)
    for _ in range(n):
        m = math.sqrt(a * b)
        fm = f(m)
        if (fm > 0) == (fa > 0):
            a, fa = m, fm
        else:
            b = m
    return math.sqrt(a * b)


def stability_margins(loop: Callable[[np.ndarray], np.ndarray], w_min: float = 1e-2,
                      w_max: float = 1e4, n: int = 4000) -> Margins:
    """Margins of the loop ``L(jw)`` (a vectorised function of w in rad/s).

    The phase is unwrapped from the lowest frequency; the phase crossover is the first
    frequency where it passes -180 deg, the gain crossover the last where |L| passes 1.
    """
    w = np.logspace(math.log10(w_min), math.log10(w_max), n)
    Lw = loop(w)
    mag = np.abs(Lw)
    ph = np.unwrap(np.angle(Lw))

    def phase_at(x: float) -> float:
        # continuous with the unwrapped grid: nearest grid phase + wrapped difference
        k = int(np.clip(np.searchsorted(w, x), 0, n - 1))
        p = float(np.angle(loop(np.array([x]))[0]))
        return p + 2 * math.pi * round((ph[k] - p) / (2 * math.pi))

    wc = math.nan
    above = mag > 1
    idx = np.flatnonzero(above[:-1] != above[1:])
    if idx.size:
        k = int(idx[-1])
        wc = _bisect(lambda x: float(np.abs(loop(np.array([x]))[0])) - 1.0, w[k], w[k + 1])
    w180 = math.nan
    gm = math.inf
    below = ph < -math.pi
    jdx = np.flatnonzero(below[:-1] != below[1:])
    if jdx.size:
        k = int(jdx[0])
        w180 = _bisect(lambda x: phase_at(x) + math.pi, w[k], w[k + 1])
        gm = 1.0 / float(np.abs(loop(np.array([w180]))[0]))
    if math.isfinite(wc):
        pm = math.degrees(phase_at(wc) + math.pi)
        dm = math.radians(pm) / wc if pm > 0 else 0.0
    else:
        pm, dm = math.inf, math.inf
    return Margins(gm, pm, wc, w180, dm)
