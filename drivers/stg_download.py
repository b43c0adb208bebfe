"""One trial's STG download, prepared and checked without touching the device.

:func:`prepare_download` is the single code path from a
:class:`~nmsid.drivers.interfaces.CheckedWaveform` to the arrays ``PrepareAndSendData`` receives:
:meth:`nmsid.drivers.stg4002.Stg4002Stimulator.load` sends what it returns, and
``nmsid stimulation`` (:mod:`nmsid.cli.stimulation_command`) reports on it, so what a lab
hands its ethics committee is what the device would play.

Checks, in order, each refusing with nothing sent: the waveform's ceilings against the
rig's and the device's; the envelope peak; rendering (charge-balanced carrier, see
:mod:`nmsid.drivers.stg_waveform`); the rendered peak
(:func:`~nmsid.drivers.stg_waveform.check_rendered`); the net charge of every carrier period
(:func:`~nmsid.drivers.stg_waveform.check_charge_balance`).

Memory: the download format's size on the device is not documented; :data:`BYTES_PER_POINT`
is a conservative estimate per (value, duration) point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nmsid.drivers.errors import DeviceRangeError, StimulatorSettingError
from nmsid.drivers.interfaces import CheckedWaveform, CurrentLimitError
from nmsid.drivers.stg_waveform import (
    NA_PER_MA,
    RenderedChannel,
    check_charge_balance,
    check_rendered,
    compress,
    output_tick_us,
    render_channel,
)

BYTES_PER_POINT = 8
"""Conservative device-memory estimate per (value, duration) point (not documented)."""
STG4002_OUTPUT_RATE_HZ = 50_000.0
"""STG4000 series: 20 us time resolution (McsUsbNet ``PrepareAndSendData``: "The STG has a
resolution of 20 us"); the default the driver sets with ``SetOutputRate``."""
STG4002_RANGE_NA = 16_000_000
"""STG4002-16mA: +-16 mA per channel (the device's own value is read at connect)."""
STG4002_RESOLUTION_NA = 500
"""Nominal current step assumed when no device is connected (``nmsid stimulation``)."""
MIN_OUTPUT_RATE_HZ, MAX_OUTPUT_RATE_HZ = 1000.0, 50_000.0
"""McsUsbNet ``SetOutputRate``: "Valid rates are from 1000 Hz to 50000 Hz"."""


@dataclass(frozen=True)
class ChannelPlan:
    """What the driver knows about one output channel (numbered from 1)."""

    channel: int
    name: str
    ceiling_mA: float
    range_nA: float
    resolution_nA: float


@dataclass(frozen=True, eq=False)
class PreparedDownload:
    """The checked download of one trial."""

    channels: dict[int, RenderedChannel]
    names: dict[int, str]
    sync: RenderedChannel
    sync_out: int
    duration_s: float
    output_rate_Hz: float
    worst_net_nC: dict[int, float] = field(default_factory=dict)

    def channel_bytes(self) -> dict[int, int]:
        """Estimated device memory per output channel (bytes)."""
        return {ch: r.n_points * BYTES_PER_POINT for ch, r in self.channels.items()}

    @property
    def sync_bytes(self) -> int:
        return self.sync.n_points * BYTES_PER_POINT


SYNC_HIGH = 0x01
"""Sync output level bit: high for the whole trial (the A/D's trigger and sync channel)."""
SYNC_SAVE_STOP = 0x02
"""McsUsbNet ``SendStop(triggermap, options)``, STOP_OPTION_SAVESTOP: "bypasses the stop
commands when a syncout ... has bit 1 (0x02) set. Can be used e.g. to prevent a stop while
a biphasic stimulation pulse is active" (XML)."""


def save_stop_marks(channels: list[RenderedChannel], n_ticks: int) -> np.ndarray:
    """Sync samples of one trial: bit 0 high throughout, bit 1 inside carrier periods.

    Bit 1 (:data:`SYNC_SAVE_STOP`) is set on every output tick of a carrier period in which
    any channel is non-zero, except the period's first tick, where every channel is exactly
    0 nA (``q[0] = 0``, :mod:`nmsid.drivers.stg_waveform`) and the period's net charge is
    zero. A save stop (``STOP_OPTION_SAVESTOP``) therefore takes effect only at a period
    boundary and never leaves the net charge of a cut biphasic period.
    """
    out = np.full(n_ticks, SYNC_HIGH, dtype=np.int64)
    for ch in channels:
        P = ch.period_ticks
        samples = ch.expand()[:n_ticks]
        if P <= 0 or not len(samples):
            continue
        n_periods = -(-len(samples) // P)
        padded = np.zeros(n_periods * P, dtype=np.int64)
        padded[:len(samples)] = samples
        active = np.any(padded.reshape(n_periods, P) != 0, axis=1)
        mark = np.repeat(active, P)
        mark[::P] = False
        mark = mark[:n_ticks]
        out[:len(mark)] |= np.where(mark, SYNC_SAVE_STOP, 0)
    return out


def check_output_rate(output_rate_Hz: float) -> float:
    """Validate an output rate (1 kHz .. 50 kHz, whole microseconds per sample).

    Raises
    ------
    StimulatorSettingError
    """
    rate = float(output_rate_Hz)
    if not MIN_OUTPUT_RATE_HZ <= rate <= MAX_OUTPUT_RATE_HZ:
        raise StimulatorSettingError(
            f"STG output rate {rate:g} Hz is outside 1000 .. 50000 Hz (McsUsbNet "
            "SetOutputRate: valid rates are from 1000 Hz to 50000 Hz)")
    output_tick_us(rate)
    return rate


def prepare_download(waveform: CheckedWaveform, ext: ChannelPlan, flex: ChannelPlan,
                     sync_out: int, output_rate_Hz: float) -> PreparedDownload:
    """Render and check one trial for download; see the module docstring.

    Raises
    ------
    DeviceRangeError, CurrentLimitError, ChargeBalanceError, StimulatorSettingError
        Nothing may be sent then.
    """
    rendered: dict[int, RenderedChannel] = {}
    worst: dict[int, float] = {}
    for plan, env, wf_ceiling in ((ext, waveform.I_ext_mA, waveform.ceiling_ext_mA),
                                  (flex, waveform.I_flex_mA, waveform.ceiling_flex_mA)):
        limit = min(wf_ceiling, plan.ceiling_mA, plan.range_nA / NA_PER_MA)
        if wf_ceiling > plan.ceiling_mA + 1e-12:
            raise DeviceRangeError(
                f"{plan.name} waveform ceiling {wf_ceiling:g} mA exceeds the rig ceiling "
                f"{plan.ceiling_mA:g} mA of stimulator channel {plan.channel}; nothing was "
                "sent")
        if env.size and env.max() > limit:
            raise CurrentLimitError(f"{plan.name} envelope peak {env.max():.4f} mA exceeds "
                                    f"{limit:.4f} mA; nothing was sent")
        r = render_channel(env, waveform.fs_Hz, waveform.carrier_Hz, output_rate_Hz,
                           plan.resolution_nA)
        # the last checks, on exactly the arrays that are sent
        label = f"{plan.name} channel {plan.channel}"
        check_rendered(r, limit, label)
        worst[plan.channel] = check_charge_balance(r, plan.resolution_nA, label)
        rendered[plan.channel] = r
    tick = output_tick_us(output_rate_Hz)
    n_ticks = int(round(waveform.duration_s * output_rate_Hz))
    sync = compress(save_stop_marks(list(rendered.values()), n_ticks), tick)
    return PreparedDownload(channels=rendered, names={ext.channel: ext.name,
                                                      flex.channel: flex.name},
                            sync=sync, sync_out=sync_out,
                            duration_s=n_ticks / output_rate_Hz,
                            output_rate_Hz=output_rate_Hz, worst_net_nC=worst)
