"""Activation dynamics: each muscle's activation lags its drive by a first-order filter
``1 / (tau_s s + 1)`` (slot ``lag``); both muscles share it, so the force is
``G(s) / (tau_s s + 1)`` of the drive."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param
from nmsid.protocols.effect_defs.dead_time import LOG_TIME_BOUNDS, LOG_TIME_GRID


@dataclass(frozen=True)
class ActivationDynamics(EffectParams):
    """An extra first-order lag ``1 / (tau_s s + 1)`` of each muscle's activation."""

    tau_s: float = param("the activation time constant, s", 0.0, 5.0)

    name: ClassVar[str] = "activation_dynamics"
    summary: ClassVar[str] = "each muscle's activation lags its drive by a first-order filter"
    definition: ClassVar[str] = ("a(s) = u(s) / (tau_s s + 1) for each muscle, so the force is "
                                 "G(s) / (tau_s s + 1) of the drive")
    slots: ClassVar[frozenset[str]] = frozenset({"lag"})
    words: ClassVar[str | None] = ("slower muscle activation (a first-order lag before the "
                                       "force dynamics)")
    confusable_with: ClassVar[tuple[str, ...]] = ("flexor_extensor_asymmetry",)

    def lag_s(self) -> float:
        return self.tau_s


class ActivationDynamicsForm(FittedForm):
    """A first-order lag ``1 / (tau s + 1)``; ``q = log tau``."""

    bounds = LOG_TIME_BOUNDS

    def grid(self):
        return [[float(np.log(v))] for v in LOG_TIME_GRID]

    def physical(self, q):
        return {"tau_s": float(np.exp(q[0]))}

    def fit_lag_s(self, q):
        return float(np.exp(q[0]))

    def twin_params(self, p, sE_levels):
        return {"tau_s": p["tau_s"]}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: the footprint's phase is an arctangent (R^2 "
                f"{tf.r2_atan_phase:.3f} vs {tf.r2_linear_phase:.3f} for a line; tau "
                f"= {1000 * tf.lag_equivalent_s:.1f} ms) with a gain roll-off of "
                f"{tf.gain_error_at_top_dB:.2f} dB at the top of the band (expected "
                f"{tf.gain_rolloff_expected_for_lag_dB:.2f} dB).")


EFFECT = EffectDefinition(ActivationDynamics, ActivationDynamicsForm())
