"""``[stimulator]`` with ``kind = "rehamove3"``: the Hasomed RehaMove3 (ScienceMode4, low
level).

Keys as for the other stimulators (``extensor_channel``, ``flexor_channel``,
``ceiling_ext_mA``, ``ceiling_flex_mA``, ``pulse_rate_Hz``, ``pulse_width_us``) plus
``interphase_us``. Limits from the RehaMove3 ScienceMode description 2018-04-21 (*RM3*:
1.2, 1.5, 4.2); the cross-key rules are the driver's
(:func:`nmsid.drivers.sciencemode4.check_settings`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictFloat, StrictInt, StrictStr, model_validator

from nmsid.drivers.errors import hw_config_error
from nmsid.drivers.sciencemode4 import REHAMOVE3, settings_problem
from nmsid.protocols.settings_base import bounded, settings_dataclass

Rm3Channel = Annotated[StrictInt, Field(ge=1, le=4, description=(
    "RehaMove3 channels 1 .. 4: red, blue, black, white (RM3 1.5)"))]


@settings_dataclass(hw_config_error, prefix="stimulator")
class Rehamove3Config:
    """``[stimulator]`` of a RehaMove3: its port, channels, ceilings and pulse settings."""

    kind: Literal["rehamove3"] = "rehamove3"
    port: StrictStr = ""
    extensor_channel: Rm3Channel = 1
    flexor_channel: Rm3Channel = 2
    ceiling_ext_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the RehaMove3's output, RM3 1.2)"))
    ceiling_flex_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the RehaMove3's output, RM3 1.2)"))
    pulse_rate_Hz: StrictFloat = bounded(40.0, ge=1.0, le=100.0, why=(
        "pulses per second per channel, 1 .. 100 Hz (host-timed low level)"))
    pulse_width_us: StrictInt = bounded(300, ge=20, le=4095, why=(
        "width of each phase, 20 .. 4095 us (RM3 1.2; one point, RM3 4.2)"))
    mode: Literal["low", "mid"] = Field("low", description=(
        "low: one command per pulse, host-timed; mid: the device times the pulses, kept "
        "alive every 0.5 s (RM3 1.4, 4, 5)"))
    interphase_us: StrictInt = bounded(100, ge=0, le=4095, why=(
        "pause between the two phases, 0 .. 4095 us (RM3 4.2)"))

    @model_validator(mode="after")
    def _check(self):
        problem = settings_problem(REHAMOVE3, self)
        if problem is not None:
            raise problem
        return self
