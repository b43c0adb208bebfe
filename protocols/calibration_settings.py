"""The ``[calibration]`` table of a session configuration: ramps, ceilings, manual currents.

Part of :mod:`nmsid.protocols.config` (which re-exports every name); bounds and their reasons
sit next to the fields (``docs/settings.md``).
"""

from __future__ import annotations

from pydantic import StrictBool, StrictFloat, model_validator

from nmsid.protocols.errors import ConfigError
from nmsid.protocols.joints import JOINTS
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass

MAX_RAMP_STEPS = 2000
"""Calibration steps per ramp at most (ceiling / step_mA); the paper's: 32."""

_ELBOW = JOINTS["elbow"]
"""The defaults below are the elbow's; a session on another joint takes that joint's
(``Config``'s ``joint``). Fmin_N, Fmax_N and force_ceiling_N are in the joint's unit (N m
for a torque joint)."""

_CURRENT_WHY = ("no transcutaneous stimulator of this rig delivers more than 100 mA; the "
                "device's own range is checked when it is connected")


@settings_dataclass(ConfigError, prefix="calibration.manual")
class ManualCurrents:
    """Calibration currents entered by hand (skips the ramps)."""

    Iemin_mA: StrictFloat = bounded(ge=0.0, le=100.0, why=_CURRENT_WHY)
    Iemax_mA: StrictFloat = bounded(ge=0.0, le=100.0, why=_CURRENT_WHY)
    Ifmin_mA: StrictFloat = bounded(ge=0.0, le=100.0, why=_CURRENT_WHY)
    Ifmax_mA: StrictFloat = bounded(ge=0.0, le=100.0, why=_CURRENT_WHY)

    @model_validator(mode="after")
    def _ordered(self):
        if not self.Iemax_mA > self.Iemin_mA:
            raise SettingProblem("Iemax_mA", self.Iemax_mA,
                                 f"above Iemin_mA ({self.Iemin_mA:g} mA)")
        if not self.Ifmax_mA > self.Ifmin_mA:
            raise SettingProblem("Ifmax_mA", self.Ifmax_mA,
                                 f"above Ifmin_mA ({self.Ifmin_mA:g} mA)")
        return self


@settings_dataclass(ConfigError, prefix="calibration")
class CalibrationConfig:
    """Settings of the calibration ramps (paper: 0.5 mA steps, Fmin 0.5 N, Fmax 5 N)."""

    step_mA: StrictFloat = bounded(0.5, ge=0.01, le=5.0, why=(
        "ramp steps from 0.01 mA (below it the force cannot tell two steps apart) to 5 mA "
        "(a coarser ramp jumps past Fmin); the paper: 0.5 mA"))
    hold_s: StrictFloat = bounded(1.0, gt=0.0, le=10.0, why=(
        "each ramp step stimulates for at most 10 s: longer fatigues the muscle before "
        "the schedule starts; the paper: 1 s"))
    settle_fraction: StrictFloat = bounded(0.5, ge=0.0, lt=1.0, why=(
        "the part of each hold ignored before averaging; some of it must remain"))
    baseline_s: StrictFloat = bounded(1.0, gt=0.0, le=60.0, why=(
        "a zero-current recording of at most a minute tares the force"))
    rest_s: StrictFloat = bounded(2.0, ge=0.0, le=600.0, why=(
        "output off before each ramp for at most 10 min"))
    Fmin_N: StrictFloat = bounded(_ELBOW.Fmin, gt=0.0, le=1000.0, why=(
        "a force or torque a joint can produce (at most 1 kN or 1 kN m)"))
    Fmax_N: StrictFloat = bounded(_ELBOW.Fmax, gt=0.0, le=1000.0, why=(
        "a force or torque a joint can produce (at most 1 kN or 1 kN m)"))
    ceiling_ext_mA: StrictFloat = bounded(16.0, gt=0.0, le=100.0, why=_CURRENT_WHY)
    ceiling_flex_mA: StrictFloat = bounded(16.0, gt=0.0, le=100.0, why=_CURRENT_WHY)
    force_ceiling_N: StrictFloat = bounded(_ELBOW.ceiling, gt=0.0, le=1000.0, why=(
        "a force or torque a joint can produce (at most 1 kN or 1 kN m)"))
    confirm: StrictBool = False
    manual: ManualCurrents | None = None

    @model_validator(mode="after")
    def _consistent(self):
        if self.Fmax_N <= self.Fmin_N:
            raise SettingProblem("Fmax_N", self.Fmax_N, f"above Fmin_N ({self.Fmin_N:g} N)")
        if self.force_ceiling_N <= self.Fmax_N:
            raise SettingProblem("force_ceiling_N", self.force_ceiling_N,
                                 f"above Fmax_N ({self.Fmax_N:g} N), or the ramp could never "
                                 "reach Fmax")
        for name in ("ceiling_ext_mA", "ceiling_flex_mA"):
            ceiling = getattr(self, name)
            if ceiling < self.step_mA:
                raise SettingProblem(name, ceiling,
                                     f"at least one ramp step ({self.step_mA:g} mA)")
            if ceiling / self.step_mA > MAX_RAMP_STEPS:
                raise SettingProblem("step_mA", self.step_mA,
                                     f"at least {name} / {MAX_RAMP_STEPS} = "
                                     f"{ceiling / MAX_RAMP_STEPS:g} mA (a ramp of at most "
                                     f"{MAX_RAMP_STEPS} steps)")
        m = self.manual
        if m is not None:
            if m.Iemax_mA > self.ceiling_ext_mA:
                raise SettingProblem("manual.Iemax_mA", m.Iemax_mA,
                                     f"at most calibration.ceiling_ext_mA "
                                     f"({self.ceiling_ext_mA:g} mA)")
            if m.Ifmax_mA > self.ceiling_flex_mA:
                raise SettingProblem("manual.Ifmax_mA", m.Ifmax_mA,
                                     f"at most calibration.ceiling_flex_mA "
                                     f"({self.ceiling_flex_mA:g} mA)")
        return self
