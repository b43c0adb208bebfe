"""Multi Channel Systems STG4002 stimulator through McsUsbNet (.NET) via pythonnet.

Mode: **download**. A trial (15 s) is rendered and checked by
:func:`drivers.stg_download.prepare_download` (charge-balanced carrier, ceiling, net charge
per period), downloaded, and played from the device's own memory, hardware-timed.

Vendor sources, cited next to each behaviour below: McsUsbNet 5.3.15
(``github.com/multichannelsystems/McsUsbNet``: XML documentation ``x64/McsUsbNet.xml`` and
the type metadata of ``x64/McsUsbNet.dll``, see :mod:`drivers.stg_status`); MCS's examples
``multichannelsystems/McsUsbNet_Examples`` (``Examples/Python/Stimulation.py``,
``Examples/CSharp/STG_Stimulation/Form1.cs``); the ``mcs.stg.sdk`` MATLAB wrapper of
McsUsbNet (``cstg200x_download_basic.m``) for ``GetCapacity`` / ``SetCapacity``.

Sequence:

* connect: ``CMcsUsbListNet(DeviceEnumNet.MCS_STG_DEVICE)``, ``CStg200xDownloadNet()`` with
  ``Stg200xPollStatusEvent += handler(status, StgStatusNet, index_list)``,
  ``Connect(entry)``; then at once ``SendStop(all triggers)`` ("Stop some or all triggers
  of the STG", ``triggermap`` a bitmap) so a pattern left running by MC_Stimulus II or a
  crashed run stops, checked with ``QueryTriggerstatus()``; ``ResetStatus(all)``,
  ``EnableAutoReset()`` (the power-up default), ``ResetOvercurrent()`` if a shutdown is
  latched; ``SetCurrentMode()``, ``DisableMultiFileMode()`` ("trigger inputs are assigned
  to channels"), ``GetCurrentRangeInNanoAmp`` / ``GetCurrentResolutionInNanoAmp`` per
  channel, ``SetOutputRate(rate)`` + ``GetOutputRate()`` read back ("Valid rates are from
  1000 Hz to 50000 Hz"), ``GetTotalMemory()``, ``GetStgVersionInfo(out sw, out hw)``.
* load: ``ResetStatus``, the memory layout (per channel and sync output:
  ``GetCapacity`` / ``SetCapacity(channelCapacity[], syncCapacity[])``, "Make sure the
  sum does not exceed the memory"; checked before anything is sent),
  ``SetupTrigger(first, channelmap[], syncoutmap[], repeat[])``, ``ClearChannelData``,
  ``PrepareAndSendData(ch, Int32[] nA, UInt64[] us, channeldata_current)``,
  ``ClearSyncData``, ``PrepareAndSendData(s, ..., syncoutdata)``.
* start ``SendStart(1)``; stop ``SendStop(all triggers)``; ``Disconnect()``, ``Dispose()``.

Threads: every vendor call holds one lock, so a stop never runs concurrently with a
download or a disconnect (McsUsbNet does not document its objects as thread-safe).
:meth:`Stg4002Stimulator.stop_now` waits up to :data:`STOP_WAIT_S` for the lock; if a
download holds it longer, the download sends ``SendStop`` right after its current vendor
call returns, and the load ends in a fault (never LOADED).

Not verified on hardware: everything here ran against ``testing/fakes/fake_mcs_usb.py``
only (built from the same vendor material).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from types import SimpleNamespace

from drivers.errors import (DeviceError, DeviceMemoryError, DeviceNotFound,
                            DeviceRangeError, StimulatorFault, StimulatorSettingError,
                            VendorLibraryMissing)
from drivers.interfaces import (CheckedWaveform, StimulatorCapabilities, StimulatorState,
                                StimulatorStatus)
from drivers.stg_download import (BYTES_PER_POINT, STG4002_OUTPUT_RATE_HZ, ChannelPlan,
                                  PreparedDownload, check_output_rate, prepare_download)
from drivers.stg_status import (DeviceStatus, OvercurrentStatus, TriggerStatus,
                                UnknownStatus, decode_status, parse_version_info)
from drivers.stg_waveform import NA_PER_MA, RenderedChannel
from drivers.stimulation_report import download_summary

log = logging.getLogger(__name__)

DEFAULT_OUTPUT_RATE_HZ = STG4002_OUTPUT_RATE_HZ
DEFAULT_DLL = r"C:\Program Files\Multi Channel Systems\McsUsbNet\x64\McsUsbNet.dll"
STOP_WAIT_S = 0.25
"""How long :meth:`Stg4002Stimulator.stop_now` waits for a vendor call in progress."""
START_TIMEOUT_S = 1.0
"""Allowance for the start delay ("The startup delay is in the range of a few ms",
``SendStart``) and late poll events before a missing Running/end is a fault."""
EARLY_END_TOLERANCE_S = 0.02
__all__ = ["Stg4002Stimulator", "load_mcs_usb", "list_stg_devices", "StgDeviceInfo",
           "BYTES_PER_POINT", "DEFAULT_DLL", "DEFAULT_OUTPUT_RATE_HZ"]


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
    """:class:`~drivers.interfaces.Stimulator` for an MCS STG4002 in download mode.

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
    output_rate_Hz : float
        The STG's output rate, set and read back at :meth:`connect` (1000 .. 50000 Hz,
        a whole number of microseconds per sample).
    api : namespace, optional
        The loaded vendor names (for tests); default :func:`load_mcs_usb`.
    clock : callable, optional
        Monotonic seconds used for :meth:`status` (default ``time.monotonic``).
    """

    def __init__(self, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                 extensor_channel: int = 1, flexor_channel: int = 2, sync_out: int = 1,
                 serial: str = "", dll_path: str = DEFAULT_DLL,
                 output_rate_Hz: float = DEFAULT_OUTPUT_RATE_HZ, api=None, clock=None):
        if extensor_channel == flexor_channel:
            raise StimulatorSettingError("extensor_channel and flexor_channel must differ, "
                                         f"both are {extensor_channel}")
        self.ceiling_mA = {extensor_channel: float(ceiling_ext_mA),
                           flexor_channel: float(ceiling_flex_mA)}
        self.ext_ch, self.flex_ch, self.sync_out = extensor_channel, flexor_channel, sync_out
        self.serial = serial
        self.dll_path = dll_path
        self.output_rate_Hz = check_output_rate(output_rate_Hz)
        self._api = api
        self._now = clock or time.monotonic
        self._dev = None
        self._io = threading.Lock()
        """Held around every vendor call (never two at once)."""
        self._flags = threading.Lock()
        self._stop_pending = False
        """A stop_now() that found the device busy: the holder sends SendStop on release."""
        self._stop_count = 0
        self._reset_session_state()
        self.last_loaded: dict[int, RenderedChannel] = {}
        self.last_download: PreparedDownload | None = None

    def _reset_session_state(self) -> None:
        self._state = StimulatorState.DISCONNECTED
        self._caps: StimulatorCapabilities | None = None
        self._range_nA: dict[int, float] = {}
        self._res_nA: dict[int, float] = {}
        self._memory_bytes = 0
        self._n_triggers = 1
        self._n_channels = 0
        self._n_sync = 0
        self._software = self._hardware = ""
        self._duration_s = 0.0
        self._fs_Hz = 0.0
        self._t_start: float | None = None
        self._seen_running = False
        self._poll: DeviceStatus | None = None
        self._generation = 0
        self._capacity: dict[int, int] = {}
        self._error = ""
        self._stop_error = ""
        """A failed SendStop: the output may still be on; cleared only by connect()."""

    # -- vendor access ------------------------------------------------------------------
    @property
    def api(self):
        if self._api is None:
            self._api = load_mcs_usb(self.dll_path)
        return self._api

    def _u32(self, value: int):
        return self.api.UInt32(int(value))

    @property
    def _all_triggers(self) -> int:
        """Bitmap of every trigger input (``SendStop``'s ``triggermap``)."""
        return (1 << max(self._n_triggers, 1)) - 1

    def _release(self) -> None:
        """Release the device lock; first send a stop that was requested meanwhile."""
        try:
            if self._stop_pending and self._dev is not None:
                self._send_stop_locked("deferred stop (requested during a vendor call)")
        finally:
            self._io.release()

    def _send_stop_locked(self, why: str) -> None:
        """``SendStop(all triggers)``; the caller holds the device lock. Never raises."""
        self._stop_pending = False
        dev = self._dev
        if dev is None:
            return
        try:
            dev.SendStop(self._u32(self._all_triggers))
            log.info("STG SendStop(0x%x) sent: %s", self._all_triggers, why)
        except Exception as exc:  # never raise from the safety path
            self._stop_error = f"SendStop failed: {exc}"
            log.error("STG SendStop failed (%s): %s", why, exc)

    # -- connection -------------------------------------------------------------------
    def connect(self) -> None:
        """Connect (again), stop anything left running and configure the device.

        Safe to call after a USB error or twice in a row: a previous handle is released
        first and every per-session state (errors, status, capabilities) starts afresh.
        """
        if self._dev is not None:
            log.info("STG connect(): releasing the previous connection first")
            self.disconnect()
        self._reset_session_state()
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
        dev = api.CStg200xDownloadNet()
        dev.Stg200xPollStatusEvent += self._on_poll
        status = dev.Connect(entry)
        if status not in (None, 0):
            raise DeviceError(f"McsUsbNet Connect to STG {entry.SerialNumber} failed with "
                              f"status {status} (is MC_Stimulus II or another program "
                              "connected to it?)")
        self._dev = dev
        try:
            with self._io:
                self._configure_device(entry)
        except Exception:
            self.disconnect()
            raise
        self._state = StimulatorState.IDLE

    def _configure_device(self, entry) -> None:
        dev = self._dev
        self._n_triggers = int(dev.GetNumberOfTriggerInputs())
        # first: stop whatever an earlier program left running, on every trigger
        dev.SendStop(self._u32(self._all_triggers))
        log.info("STG %s: SendStop(0x%x) at connect", entry.SerialNumber, self._all_triggers)
        left = self._query_locked()
        if left is not None:
            if left.any_active:
                raise DeviceError(f"STG {entry.SerialNumber} still reports a running trigger "
                                  f"after SendStop ({[t.name for t in left.triggers]}); "
                                  "power-cycle it")
            if left.overcurrent is OvercurrentStatus.SHUTDOWN:
                log.warning("STG %s: overcurrent shutdown latched from before; "
                            "ResetOvercurrent()", entry.SerialNumber)
                dev.ResetOvercurrent()
        dev.ResetStatus(self._u32(self._all_triggers))
        dev.EnableAutoReset()
        n_channels = int(dev.GetNumberOfAnalogChannels())
        for ch in (self.ext_ch, self.flex_ch):
            if not 1 <= ch <= n_channels:
                raise StimulatorSettingError(
                    f"stimulator channel {ch} does not exist on {entry.DeviceName} "
                    f"({n_channels} channels, numbered from 1)")
        n_sync = int(dev.GetNumberOfSyncoutChannels())
        if not 1 <= self.sync_out <= n_sync:
            raise StimulatorSettingError(f"stimulator.sync_out = {self.sync_out} does not "
                                         f"exist ({n_sync} sync outputs, numbered from 1)")
        self._n_channels, self._n_sync = n_channels, n_sync
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
        # McsUsbNet SetOutputRate / GetOutputRate: "Valid rates are from 1000 Hz to 50000 Hz"
        dev.SetOutputRate(self._u32(int(self.output_rate_Hz)))
        got = float(dev.GetOutputRate())
        if abs(got - self.output_rate_Hz) > 0.5:
            raise DeviceError(f"STG output rate set to {self.output_rate_Hz:g} Hz but the "
                              f"device reports {got:g} Hz; nothing will be downloaded")
        self._memory_bytes = int(dev.GetTotalMemory())
        try:  # void GetStgVersionInfo(out string SwVersion, out string HwVersion)
            self._software, self._hardware = parse_version_info(dev.GetStgVersionInfo("", ""))
        except Exception as exc:  # informative only
            log.warning("STG GetStgVersionInfo failed: %s", exc)
        firmware = (f"software {self._software}, hardware {self._hardware}"
                    if self._software or self._hardware else "")
        self._caps = StimulatorCapabilities(
            n_channels=n_channels,
            max_current_mA=min(self._range_nA.values()) / NA_PER_MA,
            resolution_mA=max(self._res_nA.values()) / NA_PER_MA,
            output_rate_Hz=got, model=str(entry.DeviceName),
            serial=str(entry.SerialNumber), firmware=firmware)

    def capabilities(self) -> StimulatorCapabilities:
        if self._caps is None:
            raise DeviceError("the STG is not connected; call connect() first")
        return self._caps

    def disconnect(self) -> None:
        """Stop all triggers and release the device; waits for a vendor call in progress."""
        got = self._io.acquire(timeout=5.0)
        if not got:
            log.error("STG disconnect: a vendor call has not returned for 5 s; "
                      "disconnecting anyway")
        try:
            dev, self._dev = self._dev, None
            if dev is None:
                return
            try:
                dev.SendStop(self._u32(self._all_triggers))
            except Exception as exc:  # the device may be gone (USB error)
                log.warning("STG SendStop at disconnect failed: %s", exc)
            try:
                dev.Stg200xPollStatusEvent -= self._on_poll
            except Exception:
                pass
            for call in ("Disconnect", "Dispose"):
                try:
                    getattr(dev, call)()
                except Exception as exc:
                    log.warning("STG %s failed: %s", call, exc)
            self._stop_pending = False
        finally:
            if got:
                self._io.release()
            self._state = StimulatorState.DISCONNECTED

    # -- trial ----------------------------------------------------------------------
    def plans(self) -> tuple[ChannelPlan, ChannelPlan]:
        """The extensor and flexor channels as :func:`prepare_download` needs them."""
        return tuple(ChannelPlan(ch, name, self.ceiling_mA[ch], self._range_nA[ch],
                                 self._res_nA[ch])
                     for ch, name in ((self.ext_ch, "extensor"), (self.flex_ch, "flexor")))

    def load(self, waveform: CheckedWaveform) -> None:
        """Render, check and download one trial (does not start it).

        Raises
        ------
        DeviceRangeError, CurrentLimitError, ChargeBalanceError
            The waveform or its rendering breaks a ceiling or the charge balance; nothing
            is sent.
        DeviceMemoryError
            The trial does not fit the device memory; nothing is sent.
        StimulatorFault
            A stop (E-stop) arrived during the download: the trial is not loaded.
        DeviceError
            A vendor call failed.
        """
        if self._dev is None:
            raise DeviceError("the STG is not connected; call connect() first")
        stops_before = self._stop_count
        state = self.status().state  # a finished trial turns RUNNING into STOPPED here
        if state is StimulatorState.RUNNING:
            raise DeviceError("cannot load a trial while the STG is running; stop it first")
        self.capabilities()
        self.last_download = None  # until this trial is completely downloaded
        ext, flex = self.plans()
        prepared = prepare_download(waveform, ext, flex, self.sync_out, self.output_rate_Hz)
        self._io.acquire()
        try:
            self._download(prepared, stops_before)
        except _Aborted:
            pass
        except (DeviceMemoryError, StimulatorFault):
            raise
        except Exception as exc:
            self._state = StimulatorState.ERROR
            self._error = f"download failed: {exc}"
            raise DeviceError(f"STG download failed: {exc}") from exc
        finally:
            self._release()
        if self._stop_count != stops_before:
            self._state = StimulatorState.ERROR
            self._error = ("stopped (E-stop) during the download: the trial was not loaded; "
                           "load it again")
            log.error("STG: %s", self._error)
            raise StimulatorFault(f"STG: {self._error}")
        self.last_download = prepared
        self.last_loaded = dict(prepared.channels)
        self._error = ""  # a fresh, complete download clears an earlier fault
        self._duration_s = prepared.duration_s
        self._fs_Hz = waveform.fs_Hz
        self._t_start = None
        self._state = StimulatorState.LOADED

    def _download(self, prepared: PreparedDownload, stops_before: int) -> None:
        """The vendor calls of one download; the caller holds the device lock."""
        api, dev = self.api, self._dev
        if dev is None:
            raise DeviceError("the STG was disconnected")
        dest = api.STG_DestinationEnumNet

        def check_stop():
            if self._stop_count != stops_before:
                self._send_stop_locked("E-stop during the download")
                raise _Aborted

        check_stop()
        dev.ResetStatus(self._u32(self._all_triggers))  # no status leaks into this trial
        latched = self._query_locked()
        if latched is not None and latched.overcurrent is OvercurrentStatus.SHUTDOWN:
            log.warning("STG: clearing the overcurrent shutdown of the previous trial "
                        "(ResetOvercurrent) for a new download")
            dev.ResetOvercurrent()
        self._poll = None
        self._fit_memory(prepared)
        check_stop()
        self._setup_trigger()
        for ch, data in prepared.channels.items():
            check_stop()
            dev.ClearChannelData(self._u32(ch - 1))
            dev.PrepareAndSendData(self._u32(ch - 1),
                                   api.Array[api.Int32](data.values_nA.tolist()),
                                   api.Array[api.UInt64](data.durations_us.tolist()),
                                   dest.channeldata_current)
        check_stop()
        sync = prepared.sync
        dev.ClearSyncData(self._u32(self.sync_out - 1))
        dev.PrepareAndSendData(self._u32(self.sync_out - 1),
                               api.Array[api.Int32](sync.values_nA.tolist()),
                               api.Array[api.UInt64](sync.durations_us.tolist()),
                               dest.syncoutdata)
        check_stop()

    def _fit_memory(self, prepared: PreparedDownload) -> None:
        """Check (and if needed lay out) the per-channel and sync memory before sending.

        ``SetCapacity(channelCapacity[], syncCapacity[])`` (``mcs.stg.sdk`` wrapper of
        McsUsbNet): "Each channel and sync output can be given an individual amount of
        memory space ... Make sure the sum does not exceed the memory"; a download larger
        than its channel's capacity fails in the vendor library, mid-download.
        """
        need_ch = [0] * self._n_channels
        for ch, nbytes in prepared.channel_bytes().items():
            need_ch[ch - 1] = nbytes
        need_sync = [0] * self._n_sync
        need_sync[self.sync_out - 1] = prepared.sync_bytes
        total_need = sum(need_ch) + sum(need_sync)
        if total_need > self._memory_bytes:
            raise DeviceMemoryError(
                f"trial needs about {total_need / 1e6:.1f} MB of STG memory (estimated "
                f"{BYTES_PER_POINT} B/point), the device has {self._memory_bytes / 1e6:.1f} "
                "MB; shorten the trial; nothing was sent")
        caps = self._get_capacity()
        if caps is None:
            return  # this McsUsbNet has no download-mode GetCapacity: total checked above
        cap_ch, cap_sync = caps
        self._capacity = {ch + 1: c for ch, c in enumerate(cap_ch)}
        if _fits(need_ch, cap_ch) and _fits(need_sync, cap_sync):
            return
        n = len(need_ch) + len(need_sync)
        share = (self._memory_bytes - total_need) // n
        new_ch = [need + share for need in need_ch]
        new_sync = [need + share for need in need_sync]
        api = self.api
        self._dev.SetCapacity(api.Array[api.UInt32](new_ch), api.Array[api.UInt32](new_sync))
        log.info("STG memory laid out per channel %s and sync %s bytes (SetCapacity)",
                 new_ch, new_sync)
        caps = self._get_capacity()
        if caps is not None:
            self._capacity = {ch + 1: c for ch, c in enumerate(caps[0])}
        if caps is not None and not (_fits(need_ch, caps[0]) and _fits(need_sync, caps[1])):
            raise DeviceMemoryError(
                f"STG memory layout did not take: channels need {need_ch} bytes, sync "
                f"{need_sync}; the device reports capacities {list(caps[0])} and "
                f"{list(caps[1])}; nothing was sent")

    def _get_capacity(self):
        """``GetCapacity(out UInt32[] channel, out UInt32[] sync)`` or None if absent."""
        try:  # pythonnet: out parameters are placeholders and come back in the tuple
            result = self._dev.GetCapacity(None, None)
        except AttributeError:  # McsUsbNet 5.3.15 has no download-mode GetCapacity
            return None
        if isinstance(result, tuple) and len(result) >= 2:
            return [int(x) for x in result[-2]], [int(x) for x in result[-1]]
        return None

    def _setup_trigger(self) -> None:
        api = self.api
        n = self._n_triggers
        channelmap, syncoutmap, repeat = [0] * n, [0] * n, [0] * n
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
        self._io.acquire()
        try:
            self._poll = None
            self._seen_running = False
            self._generation += 1
            self._dev.SendStart(self._u32(1))  # trigger 1 (bit 0)
        except Exception as exc:
            self._state = StimulatorState.ERROR
            self._error = f"SendStart failed: {exc}"
            raise DeviceError(f"STG SendStart failed: {exc}") from exc
        finally:
            self._release()
        self._t_start = self._now()
        self._state = StimulatorState.RUNNING

    def stop_now(self) -> None:
        """``SendStop`` on every trigger at once. Thread-safe, idempotent, never raises.

        Never concurrent with another vendor call: if one is in progress for longer than
        :data:`STOP_WAIT_S` (a download), its thread sends the stop as soon as that call
        returns, and a download ends in a fault instead of LOADED.
        """
        with self._flags:
            self._stop_count += 1
            self._stop_pending = True
        if self._dev is None:
            self._stop_pending = False
            return
        if self._io.acquire(timeout=STOP_WAIT_S):
            try:
                if self._stop_pending:
                    self._send_stop_locked("stop_now")
            finally:
                self._io.release()
        else:
            log.warning("STG busy for more than %.2f s (download in progress): SendStop "
                        "follows as soon as the current vendor call returns", STOP_WAIT_S)
        if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED,
                           StimulatorState.LOADED):
            self._state = StimulatorState.STOPPED

    def _fault(self, message: str) -> None:
        """Output to zero, state ERROR with ``message``, logged; the caller holds the lock."""
        self._send_stop_locked(message)
        self._state = StimulatorState.ERROR
        self._error = message
        log.error("STG fault: %s (output stopped)", message)

    # -- status -----------------------------------------------------------------------
    def _on_poll(self, status, stg_status, index_list) -> None:
        """McsUsbNet poll-status callback (runs on the library's thread)."""
        try:
            ds = decode_status(stg_status)
        except UnknownStatus as exc:
            log.error("STG poll status: %s", exc)
            self._error = self._error or str(exc)
            return
        self._poll = ds
        if ds.trigger(0) in (TriggerStatus.RUNNING, TriggerStatus.FINISHED):
            self._seen_running = True  # a short Running may fall between two queries

    def _query_locked(self) -> DeviceStatus | None:
        """``QueryTriggerstatus()`` decoded, or None if this McsUsbNet lacks it."""
        query = getattr(self._dev, "QueryTriggerstatus", None)
        if query is None:
            return None
        return decode_status(query())

    def status(self) -> StimulatorStatus:
        if self._state is StimulatorState.RUNNING and self._t_start is not None:
            if self._io.acquire(blocking=False):
                try:
                    self._update_running()
                finally:
                    self._release()
        state = self._state
        index = -1
        if state is StimulatorState.RUNNING and self._t_start is not None:
            index = int((self._now() - self._t_start) * self._fs_Hz)
        return StimulatorStatus(state=state,
                                output_active=state is StimulatorState.RUNNING
                                or bool(self._stop_error),
                                error=self._stop_error or self._error, sample_index=index)

    def _update_running(self) -> None:
        """Decide from the device's own status whether the trial runs, ended or faulted."""
        elapsed = self._now() - self._t_start
        ds = None
        if self._dev is not None:
            try:
                ds = self._query_locked()
            except UnknownStatus as exc:
                self._fault(str(exc))
                return
            except Exception as exc:
                self._fault(f"status query failed: {exc}")
                return
        if ds is None:
            ds = self._poll
        if ds is None:  # nothing reported by this McsUsbNet: the host's clock decides
            if elapsed >= self._duration_s:
                self._state = StimulatorState.STOPPED
            return
        if ds.overcurrent is OvercurrentStatus.SHUTDOWN:
            self._fault(f"overcurrent shutdown after {elapsed:.3f} s: an electrode lost "
                        "contact (Stg5OvercurrentStatus Shutdown); check the electrodes")
            return
        trig = ds.trigger(0)
        if trig is TriggerStatus.RUNNING:
            self._seen_running = True
        ended = trig is TriggerStatus.FINISHED or (trig is TriggerStatus.IDLE
                                                   and self._seen_running)
        if ended:
            if elapsed < self._duration_s - EARLY_END_TOLERANCE_S:
                self._fault(f"the STG ended the pattern after {elapsed:.3f} s of "
                            f"{self._duration_s:.3f} s (trigger status {trig.name}; a "
                            "second pulse on its trigger input stops it)")
                return
            self._state = StimulatorState.STOPPED
            return
        if elapsed > self._duration_s + START_TIMEOUT_S:
            if trig is TriggerStatus.IDLE:  # ended between two queries, Running never seen
                log.warning("STG never reported Running; trial taken as ended after %.3f s",
                            elapsed)
                self._state = StimulatorState.STOPPED
            else:
                self._fault(f"the STG still reports {trig.name} {elapsed:.3f} s after a "
                            f"{self._duration_s:.3f} s trial started")

    def delivery_summary(self) -> dict | None:
        """Charge and current figures of the last download (session file
        ``stimulation_json``), or None before the first load."""
        if self.last_download is None:
            return None
        return download_summary(self.last_download, self._capacity or None)

    def describe(self) -> dict:
        """What ``nmsid probe`` prints (after :meth:`connect`)."""
        caps = self.capabilities()
        return {"model": caps.model, "serial": caps.serial,
                "software": self._software, "hardware": self._hardware,
                "channels": caps.n_channels, "output_rate_Hz": caps.output_rate_Hz,
                "range_mA": {ch: r / NA_PER_MA for ch, r in self._range_nA.items()},
                "resolution_uA": {ch: r / 1000 for ch, r in self._res_nA.items()},
                "memory_MB": self._memory_bytes / 1e6,
                "ceiling_mA": dict(self.ceiling_mA)}


class _Aborted(Exception):
    """Internal: a stop arrived during a download (turned into StimulatorFault)."""


def _fits(need: list[int], capacity: list[int]) -> bool:
    return all(n <= (capacity[i] if i < len(capacity) else 0) for i, n in enumerate(need))
