"""``[stimulator]`` with ``kind = "rehastim2"``: the Hasomed RehaStim2 (ScienceMode2).

Keys named as for the STG4002 where they mean the same (``extensor_channel``,
``flexor_channel``, ``ceiling_ext_mA``, ``ceiling_flex_mA``); the pulse settings have
defaults. Limits from the ScienceMode2 description v1.24 (SM2 Table 1 and 4.3).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictFloat, StrictInt, StrictStr, model_validator

from nmsid.drivers import rehastim2_protocol as sm2
from nmsid.drivers.errors import hw_config_error
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass

Rs2Channel = Annotated[StrictInt, Field(ge=1, le=8, description=(
    "RehaStim2 channels are numbered 1 .. 8 (ScienceMode2 Table 3)"))]


@settings_dataclass(hw_config_error, prefix="stimulator")
class Rehastim2Config:
    """``[stimulator]`` of a RehaStim2: its port, channels, ceilings and pulse settings."""

    kind: Literal["rehastim2"] = "rehastim2"
    port: StrictStr = ""
    extensor_channel: Rs2Channel = 1
    flexor_channel: Rs2Channel = 2
    ceiling_ext_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the RehaStim2's range, ScienceMode2 Table 1)"))
    ceiling_flex_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the RehaStim2's range, ScienceMode2 Table 1)"))
    pulse_rate_Hz: StrictFloat = bounded(40.0, ge=1.0, le=50.0, why=(
        "pulses per second per channel, 1 .. 50 Hz (ScienceMode2 Table 1)"))
    pulse_width_us: StrictInt = bounded(300, ge=20, le=500, why=(
        "width of each phase, 20 .. 500 us (ScienceMode2 4.3)"))

    @model_validator(mode="after")
    def _check(self):
        if not self.port:
            raise SettingProblem("port", "", "the RehaStim2's serial port (COM5, "
                                 "/dev/ttyUSB0; Device Manager, ScienceMode2 2.1)")
        if self.extensor_channel == self.flexor_channel:
            raise SettingProblem("flexor_channel", self.flexor_channel,
                                 "must differ from extensor_channel")
        try:
            sm2.main_interval_code(self.pulse_rate_Hz)
        except ValueError:
            raise SettingProblem("pulse_rate_Hz", self.pulse_rate_Hz,
                                 "1000 / rate ms must be 1 ms + k x 0.5 ms, >= 8 ms (e.g. "
                                 "50, 40, 25, 20 Hz; ScienceMode2 4.3)") from None
        return self
