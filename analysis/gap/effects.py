"""The candidate effect names (the same as the simulator's, ``docs/twin-file.md``)."""

from __future__ import annotations

from enum import Enum


class Effect(str, Enum):
    """An unmodelled effect that the diagnosis can name (``NONE``: nothing beats nominal)."""

    NONE = "none"
    DEAD_TIME = "dead_time"
    ACTIVATION_DYNAMICS = "activation_dynamics"
    FATIGUE = "fatigue"
    RECRUITMENT_NONLINEARITY = "recruitment_nonlinearity"
    BASELINE_DRIFT = "baseline_drift"
    FLEXOR_EXTENSOR_ASYMMETRY = "flexor_extensor_asymmetry"


#: The six candidate effects, in the twin file's order of physics.
CANDIDATES = (
    Effect.RECRUITMENT_NONLINEARITY,
    Effect.ACTIVATION_DYNAMICS,
    Effect.FLEXOR_EXTENSOR_ASYMMETRY,
    Effect.DEAD_TIME,
    Effect.FATIGUE,
    Effect.BASELINE_DRIFT,
)
