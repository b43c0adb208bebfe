"""Multi Channel Systems STG4002 stimulator through McsUsbNet (.NET) via pythonnet.

Mode: **download**. A trial is 15 s; at the STG4000 series' output rate of 50 kHz (20 us
time resolution) that is 750 000 points per channel, about 12 MB for two channels at a
conservative 8 bytes per (value, duration) point, well inside the STG4002's 64 MB
(MC_Stimulus II manual for the STG4002, "Pulse Types"). Download mode plays the whole
trial from the device's own memory, hardware-timed, so a busy or slow host cannot
interrupt or distort the stimulation; streaming mode (``CStg200xStreamingNet``) would need
the host to keep the device's queue filled at 50 kHz for 15 s, and an underrun there is a
stimulation fault. Streaming would only pay off for trials longer than the memory holds
(several minutes), which the protocol does not have. :meth:`Stg4002Stimulator.load`
still checks the estimate against ``GetTotalMemory()`` before sending.

Sequence (names and argument types as in MCS's public McsUsbNet examples,
``multichannelsystems/McsUsbNet_Examples``: ``Examples/Python/Stimulation.py`` and
``Examples/CSharp/STG_Stimulation/Form1.cs``):

* ``clr.AddReference(<McsUsbNet.dll>)``; ``CMcsUsbListNet(DeviceEnumNet.MCS_STG_DEVICE)``,
  ``.Count``, ``.GetUsbListEntry(i)`` (``.SerialNumber``, ``.DeviceName``);
* ``CStg200xDownloadNet()``, ``Stg200xPollStatusEvent += handler(status, StgStatusNet,
  index_list)``, ``Connect(entry)``;
* ``SetCurrentMode()``, ``GetCurrentRangeInNanoAmp(ch)``,
  ``GetCurrentResolutionInNanoAmp(ch)``, ``GetNumberOfAnalogChannels()``,
  ``GetTotalMemory()``; ``DisableMultiFileMode()`` (triggers map to channels, as in the
  neurostim MCS plugin);
* ``SetupTrigger(first_trigger, channelmap[], syncoutmap[], repeat[])`` (``UInt32``
  arrays, one entry per trigger input, bit i = channel / sync out i);
* ``ClearChannelData(ch)``, ``PrepareAndSendData(ch, Int32[] nA, UInt64[] us,
  STG_DestinationEnumNet.channeldata_current)``; in current mode a value is a multiple of
  1 nA and durations are microseconds (McsUsbNet documentation of PrepareAndSendData, as
  quoted in the ``mcs.stg.sdk`` MATLAB wrapper); ``ClearSyncData(s)``,
  ``PrepareAndSendData(s, values, durations, STG_DestinationEnumNet.syncoutdata)``;
* ``SendStart(trigger_mask)``, ``SendStop(trigger_mask)``, ``Disconnect()``,
  ``Dispose()``.

Sync: the sync output goes high (3.3 V TTL) at onset for the whole trial and low at its
end; the A/D's start trigger is its rising edge and it is also recorded as a channel.

Not verified on hardware: the ``StgStatusNet.TiggerStatus`` semantics (vendor spelling)
used by :meth:`status`; the 8-byte memory estimate; ``GetStgVersionInfo`` returning
(status, software, hardware) through pythonnet.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from nmsid.drivers.errors import (DeviceError, DeviceNotFound, DeviceRangeError,
                                  VendorLibraryMissing)
from nmsid.drivers.interfaces import (CheckedWaveform, CurrentLimitError,
                                      StimulatorCapabilities, StimulatorState, StimulatorStatus)
from nmsid.drivers.stg_waveform import (NA_PER_MA, RenderedChannel, check_rendered, compress,
                                        output_tick_us, render_channel)

log = logging.getLogger(__name__)

DEFAULT_OUTPUT_RATE_HZ = 50_000.0
"""STG4000 series: 20 us time resolution (STG4002 manual, "Pulse Types")."""
BYTES_PER_POINT = 8
"""Conservative device-memory estimate per (value, duration) point (not documented)."""
DEFAULT_DLL = r"C:\Program Files\Multi Channel Systems\McsUsbNet\x64\McsUsbNet.dll"


def load_mcs_usb(dll_path: str) -> SimpleNamespace:
    """Import pythonnet, load McsUsbNet.dll and return the names the driver uses.

    Raises
    ------
    VendorLibraryMissing
        If pythonnet or the assembly is missing (one line saying how to install).
    """
    try:
        import clr  # noqa: PLC0415 (pythonnet; lazy: Windows vendor library)
    except ImportError:
        raise VendorLibraryMissing(
            "the Python package pythonnet", "the MCS STG4002 stimulator",
            "install it with: pip install 'nmsid[mcs]' (Windows, .NET Framework 4.x)"
        ) from None
    try:
        clr.AddReference(str(dll_path))
        from Mcs.Usb import (CMcsUsbListNet, CStg200xDownloadNet,  # noqa: PLC0415
                             DeviceEnumNet, STG_DestinationEnumNet)
        from System import Array, Int32, UInt32, UInt64  # noqa: PLC0415
    except Exception as exc:  # .NET FileNotFoundException is not a Python OSError
        raise VendorLibraryMissing(
            f"McsUsbNet.dll ({dll_path})", "the MCS STG4002 stimulator",
            "get it from github.com/multichannelsystems/McsUsbNet (or MC_Stimulus II) and "
            f"set stimulator.dll_path in the hardware config ({type(exc).__name__})"
        ) from None
    return SimpleNamespace(CMcsUsbListNet=CMcsUsbListNet, DeviceEnumNet=DeviceEnumNet,
                           CStg200xDownloadNet=CStg200xDownloadNet,
                           STG_DestinationEnumNet=STG_DestinationEnumNet, Array=Array,
                           Int32=Int32, UInt32=UInt32, UInt64=UInt64)


@dataclass(frozen=True)
class StgDeviceInfo:
    name: str
    serial: str


def list_stg_devices(api: SimpleNamespace) -> list[StgDeviceInfo]:
    devices = api.CMcsUsbListNet(api.DeviceEnumNet.MCS_STG_DEVICE)
    out = []
    for i in range(int(devices.Count)):
        entry = devices.GetUsbListEntry(api.UInt32(i))
        out.append(StgDeviceInfo(name=str(entry.DeviceName), serial=str(entry.SerialNumber)))
    return out


class Stg4002Stimulator:
    """:class:`~nmsid.drivers.interfaces.Stimulator` for an MCS STG4002 in download mode.

    Parameters
    ----------
    ceiling_ext_mA, ceiling_flex_mA : float
        The rig's hard ceilings per channel (hardware config). Refused at :meth:`connect`
        if above the device's current range; every waveform must be at or below them.
    extensor_channel, flexor_channel : int
        STG outputs, numbered from 1 as on the front panel.
    sync_out : int
        Sync output (from 1) wired to the A/D's trigger input and sync channel.
    serial : str
        Serial number to connect to; empty for the only STG present.
    dll_path : str
        Path of McsUsbNet.dll.
    api : namespace, optional
        The loaded vendor names (for tests); default :func:`load_mcs_usb`.
    clock : callable, optional
        Monotonic seconds used for :meth:`status` (default ``time.monotonic``).
    """

    def __init__(self, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                 extensor_channel: int = 1, flexor_channel: int = 2, sync_out: int = 1,
                 serial: str = "", dll_path: str = DEFAULT_DLL, api=None, clock=None):
        if extensor_channel == flexor_channel:
            raise ValueError("extensor_channel and flexor_channel must differ, both are "
                             f"{extensor_channel}")
        self.ceiling_mA = {extensor_channel: float(ceiling_ext_mA),
                           flexor_channel: float(ceiling_flex_mA)}
        self.ext_ch, self.flex_ch, self.sync_out = extensor_channel, flexor_channel, sync_out
        self.serial = serial
        self.dll_path = dll_path
        self._api = api
        self._now = clock or time.monotonic
        self._dev = None
        self._io = threading.Lock()
        self._state = StimulatorState.DISCONNECTED
        self._caps: StimulatorCapabilities | None = None
        self._range_nA: dict[int, float] = {}
        self._res_nA: dict[int, float] = {}
        self._memory_bytes = 0
        self._duration_s = 0.0
        self._fs_Hz = 0.0
        self._t_start: float | None = None
        self._last_poll: tuple[int, bool] | None = None
        self._error = ""
        self._stop_error = ""
        """A failed SendStop: the output may still be on; cleared only by connect()."""
        self.last_loaded: dict[int, RenderedChannel] = {}

    # -- connection -------------------------------------------------------------------
    @property
    def api(self):
        if self._api is None:
            self._api = load_mcs_usb(self.dll_path)
        return self._api

    def _u32(self, value: int):
        return self.api.UInt32(int(value))

    def connect(self) -> None:
        api = self.api
        devices = api.CMcsUsbListNet(api.DeviceEnumNet.MCS_STG_DEVICE)
        n = int(devices.Count)
        entries = [devices.GetUsbListEntry(self._u32(i)) for i in range(n)]
        if not entries:
            raise DeviceNotFound("no MCS STG stimulator found on USB; check the cable and "
                                 "power, and that MC_Stimulus II is closed")
        if self.serial:
            matches = [e for e in entries if str(e.SerialNumber) == self.serial]
            if not matches:
                found = ", ".join(str(e.SerialNumber) for e in entries)
                raise DeviceNotFound(f"no STG with serial {self.serial!r} (found: {found}); "
                                     "check stimulator.serial in the hardware config")
            entry = matches[0]
        elif len(entries) > 1:
            found = ", ".join(str(e.SerialNumber) for e in entries)
            raise DeviceNotFound(f"{len(entries)} STGs found ({found}); set "
                                 "stimulator.serial in the hardware config to choose one")
        else:
            entry = entries[0]
        self._error = self._stop_error = ""
        dev = api.CStg200xDownloadNet()
        dev.Stg200xPollStatusEvent += self._on_poll
        status = dev.Connect(entry)
        if status not in (None, 0):
            raise DeviceError(f"McsUsbNet Connect to STG {entry.SerialNumber} failed with "
                              f"status {status}")
        self._dev = dev
        try:
            self._configure_device(entry)
        except Exception:
            self.disconnect()
            raise
        self._state = StimulatorState.IDLE

    def _configure_device(self, entry) -> None:
        dev = self._dev
        n_channels = int(dev.GetNumberOfAnalogChannels())
        for ch in (self.ext_ch, self.flex_ch):
            if not 1 <= ch <= n_channels:
                raise ValueError(f"stimulator channel {ch} does not exist on "
                                 f"{entry.DeviceName} ({n_channels} channels, numbered "
                                 "from 1)")
        n_sync = int(dev.GetNumberOfSyncoutChannels())
        if not 1 <= self.sync_out <= n_sync:
            raise ValueError(f"stimulator.sync_out = {self.sync_out} does not exist "
                             f"({n_sync} sync outputs, numbered from 1)")
        dev.SetCurrentMode()
        dev.DisableMultiFileMode()
        for ch in (self.ext_ch, self.flex_ch):
            self._range_nA[ch] = float(dev.GetCurrentRangeInNanoAmp(self._u32(ch - 1)))
            self._res_nA[ch] = float(dev.GetCurrentResolutionInNanoAmp(self._u32(ch - 1)))
            range_mA = self._range_nA[ch] / NA_PER_MA
            if self.ceiling_mA[ch] > range_mA:
                raise DeviceRangeError(
                    f"current ceiling {self.ceiling_mA[ch]:g} mA on stimulator channel {ch} "
                    f"exceeds the device's range {range_mA:g} mA; lower the ceiling in the "
                    "hardware config")
        self._memory_bytes = int(dev.GetTotalMemory())
        firmware = ""
        try:
            info = dev.GetStgVersionInfo("", "")
            firmware = " / ".join(str(x) for x in info[1:]) if isinstance(info, tuple) else str(info)
        except Exception:  # informative only
            firmware = ""
        self._caps = StimulatorCapabilities(
            n_channels=n_channels,
            max_current_mA=min(self._range_nA.values()) / NA_PER_MA,
            resolution_mA=max(self._res_nA.values()) / NA_PER_MA,
            output_rate_Hz=DEFAULT_OUTPUT_RATE_HZ,
            model=str(entry.DeviceName), serial=str(entry.SerialNumber), firmware=firmware)

    def capabilities(self) -> StimulatorCapabilities:
        if self._caps is None:
            raise DeviceError("the STG is not connected; call connect() first")
        return self._caps

    # -- trial ----------------------------------------------------------------------
    def load(self, waveform: CheckedWaveform) -> None:
        """Render, quantise, check once more and download one trial (does not start it).

        Raises
        ------
        DeviceRangeError, CurrentLimitError
            If a ceiling exceeds the device / rig ceiling or a rendered point exceeds its
            ceiling; nothing is sent then.
        DeviceError
            If the data would not fit in the device memory or a vendor call fails.
        """
        if self._dev is None:
            raise DeviceError("the STG is not connected; call connect() first")
        state = self.status().state  # a finished trial turns RUNNING into STOPPED here
        if state is StimulatorState.RUNNING:
            raise DeviceError("cannot load a trial while the STG is running; stop it first")
        caps = self.capabilities()
        plan = ((self.ext_ch, waveform.I_ext_mA, waveform.ceiling_ext_mA, "extensor"),
                (self.flex_ch, waveform.I_flex_mA, waveform.ceiling_flex_mA, "flexor"))
        rendered: dict[int, RenderedChannel] = {}
        for ch, env, wf_ceiling, name in plan:
            limit = min(wf_ceiling, self.ceiling_mA[ch], self._range_nA[ch] / NA_PER_MA)
            if wf_ceiling > self.ceiling_mA[ch] + 1e-12:
                raise DeviceRangeError(
                    f"{name} waveform ceiling {wf_ceiling:g} mA exceeds the rig ceiling "
                    f"{self.ceiling_mA[ch]:g} mA of stimulator channel {ch}; nothing was sent")
            if env.size and env.max() > limit:
                raise CurrentLimitError(f"{name} envelope peak {env.max():.4f} mA exceeds "
                                        f"{limit:.4f} mA; nothing was sent")
            rendered[ch] = render_channel(env, waveform.fs_Hz, waveform.carrier_Hz,
                                          caps.output_rate_Hz, self._res_nA[ch])
        need = sum(r.n_points for r in rendered.values()) * BYTES_PER_POINT
        if need > self._memory_bytes:
            raise DeviceError(f"trial needs about {need / 1e6:.1f} MB of STG memory, the "
                              f"device has {self._memory_bytes / 1e6:.1f} MB; shorten the "
                              "trial")
        tick = output_tick_us(caps.output_rate_Hz)
        n_ticks = int(round(waveform.duration_s * caps.output_rate_Hz))
        sync = compress(np.ones(n_ticks, dtype=np.int64), tick)  # high, then final 0
        # the last check, on exactly the arrays that are sent
        for ch, _env, wf_ceiling, name in plan:
            check_rendered(rendered[ch], min(wf_ceiling, self.ceiling_mA[ch],
                                             self._range_nA[ch] / NA_PER_MA),
                           f"{name} channel {ch}")
        api = self.api
        dest = api.STG_DestinationEnumNet
        with self._io:
            try:
                self._setup_trigger()
                for ch, data in rendered.items():
                    self._dev.ClearChannelData(self._u32(ch - 1))
                    self._dev.PrepareAndSendData(
                        self._u32(ch - 1), api.Array[api.Int32](data.values_nA.tolist()),
                        api.Array[api.UInt64](data.durations_us.tolist()),
                        dest.channeldata_current)
                self._dev.ClearSyncData(self._u32(self.sync_out - 1))
                self._dev.PrepareAndSendData(
                    self._u32(self.sync_out - 1), api.Array[api.Int32](sync.values_nA.tolist()),
                    api.Array[api.UInt64](sync.durations_us.tolist()), dest.syncoutdata)
            except Exception as exc:
                self._state = StimulatorState.ERROR
                self._error = f"download failed: {exc}"
                raise DeviceError(f"STG download failed: {exc}") from exc
        self.last_loaded = rendered
        self._error = ""  # a fresh, complete download clears an earlier fault
        self._duration_s = n_ticks / caps.output_rate_Hz
        self._fs_Hz = waveform.fs_Hz
        self._t_start = None
        self._state = StimulatorState.LOADED

    def _setup_trigger(self) -> None:
        api = self.api
        n_triggers = int(self._dev.GetNumberOfTriggerInputs())
        channelmap = [0] * n_triggers
        syncoutmap = [0] * n_triggers
        repeat = [0] * n_triggers
        channelmap[0] = (1 << (self.ext_ch - 1)) | (1 << (self.flex_ch - 1))
        syncoutmap[0] = 1 << (self.sync_out - 1)
        repeat[0] = 1  # play once (0 would repeat forever)
        self._dev.SetupTrigger(self._u32(0), api.Array[api.UInt32](channelmap),
                               api.Array[api.UInt32](syncoutmap), api.Array[api.UInt32](repeat))

    def arm(self) -> None:
        if self._state is not StimulatorState.LOADED:
            raise DeviceError(f"cannot arm the STG while it is {self._state.value}; load a "
                              "trial first")
        self._state = StimulatorState.ARMED

    def start(self) -> None:
        if self._state is not StimulatorState.ARMED:
            raise DeviceError(f"cannot start the STG while it is {self._state.value}")
        with self._io:
            try:
                self._dev.SendStart(self._u32(1))  # trigger 1 (bit 0)
            except Exception as exc:
                self._state = StimulatorState.ERROR
                self._error = f"SendStart failed: {exc}"
                raise DeviceError(f"STG SendStart failed: {exc}") from exc
        self._t_start = self._now()
        self._state = StimulatorState.RUNNING

    def stop_now(self) -> None:
        """SendStop at once. Thread-safe, idempotent, never raises.

        If another thread holds the device (a download in progress) for more than 50 ms,
        the stop is sent anyway: a concurrent USB call is the lesser risk.
        """
        dev = self._dev
        if dev is None:
            return
        got = self._io.acquire(timeout=0.05)
        try:
            dev.SendStop(self._u32(1))
        except Exception as exc:  # never raise from the safety path
            self._stop_error = f"SendStop failed: {exc}"
            log.error("STG SendStop failed: %s", exc)
        finally:
            if got:
                self._io.release()
        if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED,
                           StimulatorState.LOADED):
            self._state = StimulatorState.STOPPED

    def _on_poll(self, status, stg_status, index_list) -> None:
        """McsUsbNet poll-status callback (runs on the library's thread)."""
        try:
            trig = stg_status.TiggerStatus  # vendor spelling
            running = bool(int(trig[0]))
        except Exception:
            running = True
        self._last_poll = (int(status), running)

    def status(self) -> StimulatorStatus:
        state = self._state
        index = -1
        if state is StimulatorState.RUNNING and self._t_start is not None:
            elapsed = self._now() - self._t_start
            poll_says_done = self._last_poll is not None and not self._last_poll[1] \
                and elapsed > 0.05
            if elapsed >= self._duration_s or poll_says_done:
                self._state = state = StimulatorState.STOPPED
            else:
                index = int(elapsed * self._fs_Hz)
        return StimulatorStatus(state=state,
                                output_active=state is StimulatorState.RUNNING
                                or bool(self._stop_error),
                                error=self._stop_error or self._error, sample_index=index)

    def disconnect(self) -> None:
        dev, self._dev = self._dev, None
        if dev is None:
            return
        try:
            dev.SendStop(self._u32(1))
        except Exception:
            pass
        for call in ("Disconnect", "Dispose"):
            try:
                getattr(dev, call)()
            except Exception as exc:
                log.warning("STG %s failed: %s", call, exc)
        self._state = StimulatorState.DISCONNECTED

    def describe(self) -> dict:
        """What ``nmsid probe`` prints (after :meth:`connect`)."""
        caps = self.capabilities()
        return {"model": caps.model, "serial": caps.serial, "firmware": caps.firmware,
                "channels": caps.n_channels,
                "range_mA": {ch: r / NA_PER_MA for ch, r in self._range_nA.items()},
                "resolution_uA": {ch: r / 1000 for ch, r in self._res_nA.items()},
                "memory_MB": self._memory_bytes / 1e6,
                "ceiling_mA": dict(self.ceiling_mA)}
