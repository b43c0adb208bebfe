"""Dead time: the force answers the stimulation ``L_s`` seconds late (``G(s) e^{-L_s s}``).

The smallest effect module: one parameter, one slot (``delay``), a fitted form on
``q = log L``. The pattern every effect module follows (:mod:`.base`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param

#: Bounds of a fitted time constant on the solver's scale (log seconds): 1 us .. 0.3 s.
LOG_TIME_BOUNDS = ((float(np.log(1e-6)), float(np.log(0.3))),)
#: Starting values of a fitted time constant, s.
LOG_TIME_GRID = (0.003, 0.008, 0.015, 0.025, 0.04, 0.06, 0.09, 0.13)


@dataclass(frozen=True)
class DeadTime(EffectParams):
    """The force responds to the stimulation ``L_s`` seconds late."""

    L_s: float = param("the delay, s", 0.0, 2.0)

    name: ClassVar[str] = "dead_time"
    summary: ClassVar[str] = "the force answers the stimulation late"
    definition: ClassVar[str] = "F(t) = F_0(t - L_s), i.e. G(s) e^{-L_s s}"
    slots: ClassVar[frozenset[str]] = frozenset({"delay"})
    words: ClassVar[str | None] = "a dead time (the force answers the stimulation late)"
    confusable_with: ClassVar[tuple[str, ...]] = ("activation_dynamics",
                                                  "flexor_extensor_asymmetry")

    def delay_s(self) -> float:
        return self.L_s


class DeadTimeForm(FittedForm):
    """``x(t) = x0(t - L)``; ``q = log L``."""

    bounds = LOG_TIME_BOUNDS

    def grid(self):
        return [[float(np.log(v))] for v in LOG_TIME_GRID]

    def physical(self, q):
        return {"L_s": float(np.exp(q[0]))}

    def fit_delay_s(self, q):
        return float(np.exp(q[0]))

    def final(self, p, ctx):
        # counted from the rE record: the rig's timing and the participant's latency
        # together (the two are one delay to the data)
        p["L_s"] = p["L_s"] + p["input_timing_s"]

    def twin_params(self, p, sE_levels):
        return {"L_s": p["L_s"]}

    def pair_evidence(self, other, sig):
        # a dead time's phase error is a line, an activation lag's an arctangent with a
        # gain roll-off: the phase shape tells the two apart
        if other != "activation_dynamics":
            return None
        tf = sig.phase
        return {"phase_shape": {"r2_linear": tf.r2_linear_phase, "r2_atan": tf.r2_atan_phase,
                                "gain_error_at_top_dB": tf.gain_error_at_top_dB}}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: the effect's footprint on the transfer function is a phase "
                f"line (R^2 {tf.r2_linear_phase:.3f} vs {tf.r2_atan_phase:.3f} for "
                f"an arctangent; slope = {1000 * tf.dead_time_equivalent_s:.1f} ms) with "
                f"a gain error of {tf.gain_error_at_top_dB:.2f} dB at the top of the "
                f"band (a lag with that phase would roll off "
                f"{tf.gain_rolloff_expected_for_lag_dB:.2f} dB).")


EFFECT = EffectDefinition(DeadTime, DeadTimeForm())
