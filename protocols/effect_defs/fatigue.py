"""Fatigue: the force's gain falls with cumulative stimulation ``c`` (slot ``gain``).

``p = gain_loss_pct / 100``; exponential: ``g = (1 - p)^(c / reference_stim_s)``; linear:
``g = max(0.05, 1 - p c / reference_stim_s)``. The fit uses ``exp(-lambda c)`` (a constant
relative loss rate; a linear decline with the same end point has the same integrated
log-slope, so the reported loss over ``reference_stim_s`` matches both).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param

#: The twin file's default reference: 45 trials x 15 s of stimulation.
REFERENCE_STIM_S = 675.0


class FatigueShape(enum.Enum):
    EXPONENTIAL = "exponential"
    LINEAR = "linear"


@dataclass(frozen=True)
class Fatigue(EffectParams):
    """Gain multiplied by ``g(c)``, c = cumulative stimulation time since the session began.

    exponential: ``g = (1 - p) ** (c / c_ref)``; linear: ``g = max(0.05, 1 - p c / c_ref)``;
    ``p = gain_loss_pct / 100``, ``c_ref = reference_stim_s`` (675 s = 45 trials x 15 s).
    """

    shape: FatigueShape = param("the decline's form", choices=FatigueShape)
    gain_loss_pct: float = param("gain lost over reference_stim_s, %", 0.0, 99.0)
    reference_stim_s: float = param("cumulative stimulation the loss refers to, s", 0.0, None,
                                    lower_open=True, required=False, default=REFERENCE_STIM_S)

    name: ClassVar[str] = "fatigue"
    summary: ClassVar[str] = "the force's gain falls with cumulative stimulation"
    definition: ClassVar[str] = (
        "F = g(c) F_0 with p = gain_loss_pct / 100; exponential: g = (1 - p)^(c / "
        "reference_stim_s); linear: g = max(0.05, 1 - p c / reference_stim_s)")
    slots: ClassVar[frozenset[str]] = frozenset({"gain"})
    words: ClassVar[str | None] = "fatigue (the response weakens with accumulated stimulation)"
    confusable_with: ClassVar[tuple[str, ...]] = ("baseline_drift",)

    def gain(self, cumulative_stim_s):
        """g(c) for c in seconds of cumulative stimulation (array or scalar)."""
        c = np.asarray(cumulative_stim_s, dtype=float)
        p = self.gain_loss_pct / 100.0
        if self.shape is FatigueShape.EXPONENTIAL:
            g = (1.0 - p) ** (c / self.reference_stim_s)
        else:
            g = np.maximum(0.05, 1.0 - p * c / self.reference_stim_s)
        return float(g) if np.ndim(g) == 0 else g


def fatigue_loss_pct(rate_per_s: float, reference_stim_s: float = REFERENCE_STIM_S) -> float:
    """Gain lost over ``reference_stim_s`` of stimulation at a constant relative rate."""
    return 100.0 * (1.0 - math.exp(-rate_per_s * reference_stim_s))


class FatigueForm(FittedForm):
    """Gain ``exp(-lambda c)``; ``q = lambda`` in 1e-3 per s."""

    bounds = ((-5.0, 5.0),)

    def grid(self):
        return [[v] for v in (-0.3, 0.0, 0.3, 0.7, 1.2)]

    def physical(self, q):
        return {"rate_per_s": float(q[0] * 1e-3)}

    def fit_gain(self, q, cumulative_stim_s):
        return np.exp(-(float(q[0]) * 1e-3) * cumulative_stim_s)

    def final(self, p, ctx):
        p["gain_loss_pct"] = fatigue_loss_pct(p["rate_per_s"])

    def twin_params(self, p, sE_levels):
        return {"shape": "exponential",
                "gain_loss_pct": max(0.0, fatigue_loss_pct(p["rate_per_s"])),
                "reference_stim_s": REFERENCE_STIM_S}

    def signature(self, sig):
        g = sig.gain_vs_stimulation
        return (f"signature: trial gain changes by {g['slope_per_100s']:+.4f} per 100 s of "
                f"cumulative stimulation (correlation {g['correlation']:+.2f}).")


EFFECT = EffectDefinition(Fatigue, FatigueForm())
