"""The twin's second-order model with dead time, as the controller sees it.

``y'' + 2 zeta wn y' + wn^2 y = Kp wn^2 v``, ``v = rE - 0.5``, force ``F = offset_N + y``
(``docs/twin-file.md``), the response delayed by ``L_s``. Sampled with a zero-order hold
at the controller's update period (exact: matrix exponential of the augmented system).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class SecondOrderPlant:
    """One operating point of the twin (an sE level)."""

    Kp: float
    """N per unit rE."""
    wn_rad_s: float
    zeta: float
    offset_N: float = 0.0
    L_s: float = 0.0
    """Dead time of the force response (the twin's ``dead_time`` effect), s."""

    def zoh(self, Ts_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Ad, Bd, C) of the undelayed model sampled with a zero-order hold at ``Ts_s``;
        state (y, y')."""
        wn, z = self.wn_rad_s, self.zeta
        A = np.array([[0.0, 1.0], [-wn * wn, -2 * z * wn]])
        B = np.array([0.0, self.Kp * wn * wn])
        M = np.zeros((3, 3))
        M[:2, :2] = A * Ts_s
        M[:2, 2] = B * Ts_s
        E = expm(M)
        return E[:2, :2], E[:2, 2], np.array([1.0, 0.0])

    def simulate(self, v: np.ndarray, Ts_s: float, x0=None) -> np.ndarray:
        """Force y (without offset) at the start of each hold interval of ``v``
        (undelayed)."""
        Ad, Bd, C = self.zoh(Ts_s)
        x = np.zeros(2) if x0 is None else np.asarray(x0, dtype=float)
        out = np.empty(len(v))
        for k, vk in enumerate(v):
            out[k] = C @ x
            x = Ad @ x + Bd * vk
        return out

    @property
    def force_span_N(self) -> tuple[float, float]:
        """Steady force over rE in [0, 1]: (offset - Kp/2, offset + Kp/2)."""
        return self.offset_N - self.Kp / 2, self.offset_N + self.Kp / 2

    def delay_samples(self, Ts_s: float) -> int:
        return math.floor(self.L_s / Ts_s + 0.5)
