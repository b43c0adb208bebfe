"""``[stimulator]`` with ``kind = "stg4002"`` (the default): the MCS STG4002.

Its channels, ceilings, sync output and output rate; the limits the device itself has are
read back when it is connected (McsUsbNet; ``drivers.stg4002``).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictFloat, StrictInt, StrictStr, model_validator

from nmsid.drivers.errors import hw_config_error
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass

MAX_CEILING_MA = 100.0
"""No STG4002 of this rig delivers more; the device's own range is checked on connect."""

StgChannel = Annotated[StrictInt, Field(ge=1, le=8, description=(
    "channels are numbered from 1 (1 .. 8)"))]


@settings_dataclass(hw_config_error, prefix="stimulator")
class Stg4002Config:
    """``[stimulator]`` of an MCS STG4002: its channels, ceilings, sync and output rate."""

    kind: Literal["stg4002"] = "stg4002"
    dll_path: StrictStr = ""
    serial: StrictStr = ""
    extensor_channel: StgChannel = 1
    flexor_channel: StgChannel = 2
    sync_out: StgChannel = 1
    ceiling_ext_mA: StrictFloat = bounded(16.0, gt=0.0, le=MAX_CEILING_MA, why=(
        "expected > 0 and <= 100 mA (the device's own range is checked when it is connected)"))
    ceiling_flex_mA: StrictFloat = bounded(16.0, gt=0.0, le=MAX_CEILING_MA, why=(
        "expected > 0 and <= 100 mA (the device's own range is checked when it is connected)"))
    output_rate_Hz: StrictFloat = bounded(50_000.0, ge=1000.0, le=50_000.0, why=(
        "the STG4002's output rate, 1000 .. 50000 Hz (McsUsbNet SetOutputRate; read back "
        "at connect)"))
    """Set with McsUsbNet ``SetOutputRate`` and read back at connect (1000 .. 50000 Hz)."""

    @model_validator(mode="after")
    def _distinct(self):
        if self.extensor_channel == self.flexor_channel:
            raise SettingProblem("flexor_channel", self.flexor_channel,
                                 "must differ from extensor_channel")
        tick_us = 1e6 / self.output_rate_Hz
        if abs(tick_us - round(tick_us)) > 1e-9:
            raise SettingProblem("output_rate_Hz", self.output_rate_Hz,
                                 "a whole number of microseconds per sample (50000, 25000, "
                                 "20000, 10000 ... Hz; McsUsbNet SetOutputRate)")
        return self
