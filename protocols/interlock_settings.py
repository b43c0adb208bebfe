"""The ``[interlock]`` table of a session configuration, and the weakened-safety rule.

Part of :mod:`nmsid.protocols.config` (which re-exports every name). A setting that weakens
protection needs ``confirm_weakened_safety = true`` (``docs/settings.md``).
"""

from __future__ import annotations

from pydantic import StrictBool, StrictFloat, model_validator

from nmsid.protocols.errors import ConfigError
from nmsid.protocols.joints import JOINTS
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass

FORCE_SENSOR_RANGE_N = 500.0
"""Rated range of the rig's force sensor (Leptrino PFS080YA501G6: 500 N per force axis;
the simulated sensor's ``range_N``). A force limit above it can never trip."""


TRIP_SWITCHES = ("trip_on_overrun", "trip_on_over_range", "trip_on_sensor_fault")
"""Interlock rules that can be switched off (each then weakens protection)."""


@settings_dataclass(ConfigError, prefix="interlock")
class InterlockConfig:
    """Thresholds of the safety interlock (see ``docs/rig.md``).

    A setting that weakens protection (a ``trip_on_*`` switched off, a force limit above
    the sensor's range) is refused unless ``confirm_weakened_safety`` is true
    (``nmsid run --allow-weakened-safety`` sets it); see :meth:`weakened`.
    """

    force_limit_N: StrictFloat = bounded(JOINTS["elbow"].limit, gt=0.0, le=10_000.0, why=(
        "no joint pushes 10 kN or 10 kN m: a larger limit is a typo"))
    """The limit on |measured|, in the session joint's unit (N at the elbow's strap, N m
    for a torque joint); its default is the joint's (``protocols/joints.py``)."""
    stall_timeout_s: StrictFloat = bounded(0.1, gt=0.0, le=10.0, why=(
        "a stalled sensor must stop stimulation quickly"))
    trip_on_overrun: StrictBool = True
    trip_on_over_range: StrictBool = True
    trip_on_sensor_fault: StrictBool = True
    estop_poll_Hz: StrictFloat = bounded(1000.0, ge=100.0, le=100_000.0, why=(
        "the switch must be seen within 10 ms; faster than 100 kHz only burns a core"))
    confirm_weakened_safety: StrictBool = False

    def weakened(self) -> list[str]:
        """Each setting that weakens protection, as ``"interlock.key = value (why)"``."""
        out = [f"interlock.{name} = false (that interlock rule never trips)"
               for name in TRIP_SWITCHES if not getattr(self, name)]
        if self.force_limit_N > FORCE_SENSOR_RANGE_N:
            out.append(f"interlock.force_limit_N = {self.force_limit_N:g} (above the force "
                       f"sensor's range, {FORCE_SENSOR_RANGE_N:g} N: it can never trip)")
        return out

    @model_validator(mode="after")
    def _confirmed(self):
        if self.confirm_weakened_safety:
            return self
        for name in TRIP_SWITCHES:
            if not getattr(self, name):
                raise SettingProblem(name, False, CONFIRM_WORDS)
        if self.force_limit_N > FORCE_SENSOR_RANGE_N:
            raise SettingProblem("force_limit_N", self.force_limit_N,
                                 f"at most the force sensor's range "
                                 f"({FORCE_SENSOR_RANGE_N:g} N), or {CONFIRM_WORDS}")
        return self


CONFIRM_WORDS = ("this weakens the safety interlock; to run anyway set interlock."
                  "confirm_weakened_safety = true in the file or pass --allow-weakened-safety "
                  "(recorded in the session)")
