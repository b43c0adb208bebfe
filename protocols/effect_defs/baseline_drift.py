"""Baseline drift: the force baseline wanders slowly and non-linearly (slot ``additive``):
``F = F_0 + b(t)``, ``b`` band-limited below ``corner_Hz`` with RMS ``amplitude_N``.

The simulator draws ``b`` as a seeded sum of sinusoids (:class:`BaselineWander`); the fit
has no solver parameter: cosines up to ``corner_Hz`` join the per-trial nuisance basis,
the bandwidth chosen on a grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param


@dataclass(frozen=True)
class BaselineWander:
    """Band-limited wander: a sum of ``n_components`` sinusoids with log-uniform
    frequencies in [corner/10, corner] and random phases, RMS ``amplitude_N``."""

    amplitude_N: float
    corner_Hz: float
    seed: int
    n_components: int = 8

    def __post_init__(self):
        rng = np.random.default_rng([int(self.seed) & 0xFFFFFFFF, 77])
        f = self.corner_Hz * 10 ** rng.uniform(-1.0, 0.0, self.n_components)
        ph = rng.uniform(0, 2 * np.pi, self.n_components)
        a = np.full(self.n_components, self.amplitude_N * math.sqrt(2.0 / self.n_components))
        object.__setattr__(self, "_f", f)
        object.__setattr__(self, "_ph", ph)
        object.__setattr__(self, "_a", a)

    def __call__(self, t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return (self._a[:, None] * np.sin(2 * np.pi * self._f[:, None] * t[None, :]  # type: ignore[attr-defined]
                                          + self._ph[:, None])).sum(axis=0)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class BaselineDrift(EffectParams):
    """Slow non-linear wander of the force baseline, band-limited below ``corner_Hz``,
    RMS ``amplitude_N`` (a seeded sum of sinusoids; the seed is the participant's)."""

    amplitude_N: float = param("RMS of the wander, N", 0.0, 100.0)
    corner_Hz: float = param("highest frequency of the wander, Hz", 0.0, 50.0, lower_open=True)

    name: ClassVar[str] = "baseline_drift"
    summary: ClassVar[str] = "the force baseline wanders slowly and non-linearly"
    definition: ClassVar[str] = ("F = F_0 + b(t), b band-limited below corner_Hz with RMS "
                                 "amplitude_N")
    slots: ClassVar[frozenset[str]] = frozenset({"additive"})
    words: ClassVar[str | None] = "a wandering or jumping baseline force"

    def additive(self, seed):
        if self.amplitude_N <= 0:
            return None
        return BaselineWander(self.amplitude_N, self.corner_Hz, seed)


class BaselineDriftForm(FittedForm):
    """Cosines up to ``corner_Hz`` in the nuisance basis; no solver parameter."""

    n = 0
    through_nuisance = True

    def final(self, p, ctx):
        p["window_nonlinear_rms_N"], p["amplitude_N"] = ctx.drift_amplitude()

    def twin_params(self, p, sE_levels):
        return {"amplitude_N": p.get("amplitude_N", 0.0), "corner_Hz": p["corner_Hz"]}

    def signature(self, sig):
        lf = sig.low_frequency
        return (f"signature: {100 * lf['share_below_chirp']:.0f} % of the residual power "
                f"lies below the chirp band, {lf['excess']:.0f} x the white-noise share.")


EFFECT = EffectDefinition(BaselineDrift, BaselineDriftForm())
