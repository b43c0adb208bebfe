"""``[stimulator]`` with ``kind = "p24"``: the Hasomed P24 (ScienceMode4, low level).

Keys as for the other stimulators (``extensor_channel``, ``flexor_channel``,
``ceiling_ext_mA``, ``ceiling_flex_mA``, ``pulse_rate_Hz``, ``pulse_width_us``) plus
``interphase_us``. Limits from the P24 Instructions for Use v1.1 (*IFU*: Technical
Specification, Tables 14 and 15); the cross-key rules are the driver's
(:func:`nmsid.drivers.sciencemode4.check_settings`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictFloat, StrictInt, StrictStr, model_validator

from nmsid.drivers.errors import hw_config_error
from nmsid.drivers.sciencemode4 import P24, settings_problem
from nmsid.protocols.settings_base import bounded, settings_dataclass

P24Channel = Annotated[StrictInt, Field(ge=1, le=8, description=(
    "P24 channels 1 .. 8: 1 .. 4 on connector 1, 5 .. 8 on connector 2 (IFU Table 14)"))]


@settings_dataclass(hw_config_error, prefix="stimulator")
class P24Config:
    """``[stimulator]`` of a P24: its port, channels, ceilings and pulse settings."""

    kind: Literal["p24"] = "p24"
    port: StrictStr = ""
    extensor_channel: P24Channel = 1
    flexor_channel: P24Channel = 2
    ceiling_ext_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the P24's output, IFU Technical Specification)"))
    ceiling_flex_mA: StrictFloat = bounded(16.0, gt=0.0, le=130.0, why=(
        "expected > 0 and <= 130 mA (the P24's output, IFU Technical Specification)"))
    pulse_rate_Hz: StrictFloat = bounded(40.0, ge=1.0, le=100.0, why=(
        "pulses per second per channel, 1 .. 100 Hz (host-timed low level)"))
    pulse_width_us: StrictInt = bounded(300, ge=10, le=4095, why=(
        "width of each phase, 10 .. 4095 us (IFU Technical Specification, Table 15)"))
    mode: Literal["low", "mid"] = Field("low", description=(
        "low: one command per pulse, host-timed; mid: the device times the pulses, kept "
        "alive every 0.5 s (IFU Low-Level and Mid-Level commands)"))
    interphase_us: StrictInt = bounded(100, ge=0, le=4095, why=(
        "pause between the two phases, 0 .. 4095 us (IFU Table 15)"))

    @model_validator(mode="after")
    def _check(self):
        problem = settings_problem(P24, self)
        if problem is not None:
            raise problem
        return self
