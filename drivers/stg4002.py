"""Multi Channel Systems STG4002 stimulator through McsUsbNet (.NET) via pythonnet.

Mode: **download**. A trial (15 s) is rendered and checked by
:func:`nmsid.drivers.stg_download.prepare_download` (charge-balanced carrier, ceiling, net charge
per period), downloaded, and played from the device's own memory, hardware-timed.

Vendor sources, cited next to each behaviour below: McsUsbNet 5.3.15
(``github.com/multichannelsystems/McsUsbNet``: XML documentation ``x64/McsUsbNet.xml`` and
the type metadata of ``x64/McsUsbNet.dll``, see :mod:`nmsid.drivers.stg_status`); MCS's examples
``multichannelsystems/McsUsbNet_Examples`` (``Examples/Python/Stimulation.py``,
``Examples/CSharp/STG_Stimulation/Form1.cs``); the ``mcs.stg.sdk`` MATLAB wrapper of
McsUsbNet (``cstg200x_download_basic.m``) for ``GetCapacity`` / ``SetCapacity``.

Sequence (each call's vendor source is cited where it is made; the whole story is in
``docs/hardware.md``, section 4): connect -> immediate ``SendStop`` on every trigger,
status and overcurrent reset, retrigger mode (``SetupRetriggerMode``), current mode, range /
resolution, memory, version; load -> ``ResetStatus``, ``SegmentSelect(0)`` and
``GetAvailableMemory``, ``SetupTrigger``, ``PrepareAndSendData`` per channel and for the
sync, memory use read back (``GetMemoryUsageDAC`` / ``GetMemoryUsageSyncout``);
``SendStart(1)``; at an ordinary end or abort the save stop ``SendStop(all,
STOP_OPTION_SAVESTOP)``, for an E-stop the immediate ``SendStop(all)``; ``Disconnect``.
Every member called is declared in :mod:`nmsid.drivers.mcs_surface` and checked against the
real assembly there.

Download mode has a fixed 20 us time resolution (STG4000 manual p.16; McsUsbNet
``PrepareAndSendData``: "The STG has a resolution of 20 us"): ``SetOutputRate`` is a
streaming-mode setting and is never called here.

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

from nmsid.drivers.errors import (
    DeviceError,
    DeviceMemoryError,
    DeviceRangeError,
    StimulatorFault,
    StimulatorSettingError,
)
from nmsid.drivers.interfaces import CheckedWaveform, StimulatorCapabilities, StimulatorState
from nmsid.drivers.mcs_usb import (
    DEFAULT_DLL,
    StgDeviceInfo,
    find_stg,
    list_stg_devices,
    load_mcs_usb,
)
from nmsid.drivers.stg_download import (
    BYTES_PER_POINT,
    STG4002_OUTPUT_RATE_HZ,
    ChannelPlan,
    PreparedDownload,
    check_output_rate,
    prepare_download,
)
from nmsid.drivers.stg_memory import fit_memory, read_usage
from nmsid.drivers.stg_status import DeviceStatus, OvercurrentStatus, parse_version_info
from nmsid.drivers.stg_tracking import StgStatusTracking
from nmsid.drivers.stg_waveform import NA_PER_MA, RenderedChannel
from nmsid.drivers.stimulation_report import download_summary
from nmsid.errors import SafetyError

log = logging.getLogger(__name__)

DEFAULT_OUTPUT_RATE_HZ = STG4002_OUTPUT_RATE_HZ
STOP_OPTION_SAVESTOP = 0x80
"""McsUsbNet ``SendStop(triggermap, options)``: "currently only STOP_OPTION_SAVESTOP (0x80) is
defined, which bypasses the stop commands when a syncout ... has bit 1 (0x02) set. Can be
used e.g. to prevent a stop while a biphasic stimulation pulse is active" (XML)."""
SAVE_STOP_WAIT_S = 0.01
"""After a save stop, how long the trigger may still run (the rest of one carrier period)
before the immediate stop follows."""
STOP_WAIT_S = 0.25
"""How long :meth:`Stg4002Stimulator.stop_now` waits for a vendor call in progress."""
__all__ = ["Stg4002Stimulator", "load_mcs_usb", "list_stg_devices", "StgDeviceInfo",
           "BYTES_PER_POINT", "DEFAULT_DLL", "DEFAULT_OUTPUT_RATE_HZ"]


class Stg4002Stimulator(StgStatusTracking):
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
        if self.output_rate_Hz != STG4002_OUTPUT_RATE_HZ:
            # manual p.16 / XML PrepareAndSendData: download mode's resolution is 20 us
            raise StimulatorSettingError(
                f"stimulator.output_rate_Hz = {output_rate_Hz:g} cannot be used: the STG4002 "
                "in download mode has a fixed 20 us resolution (50000 Hz; STG4000 manual "
                "p.16); SetOutputRate applies to streaming mode only. Remove the setting "
                "or set it to 50000")
        self._api = api
        self._now = clock or time.monotonic
        self._dev = None
        self._io = threading.Lock()
        """Held around every vendor call (never two at once)."""
        self._flags = threading.Lock()
        self._stop_pending = False
        """A stop_now() that found the device busy: the holder sends SendStop on release."""
        self._stop_count = 0
        self._stop_failures = 0
        """Failed SendStop calls (tests; each also sets the operator message)."""
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
        self._t_sent: float | None = None
        self._seen_running = False
        self._poll: DeviceStatus | None = None
        self._generation = 0
        self._capacity: dict[int, int] = {}
        self._usage: dict[str, int] = {}
        self._error = ""
        self._foreign_start = False
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

    def _send_stop_locked(self, why: str, *, save: bool = False) -> None:
        """Stop every trigger; the caller holds the device lock. Never raises.

        ``save=False``: the immediate ``SendStop(triggermap)`` (E-stop, faults). ``save=True``
        (an ordinary end or abort): ``SendStop(triggermap, STOP_OPTION_SAVESTOP)``, which the
        device defers while the sync data's bit 1 marks a carrier period in progress
        (:func:`nmsid.drivers.stg_download.save_stop_marks`); if a trigger still runs
        :data:`SAVE_STOP_WAIT_S` later, the immediate stop follows.
        """
        self._stop_pending = False
        dev = self._dev
        if dev is None:
            return
        try:
            if save:
                dev.SendStop(self._u32(self._all_triggers),
                             self.api.Int32(STOP_OPTION_SAVESTOP))
                log.info("STG SendStop(0x%x, STOP_OPTION_SAVESTOP) sent: %s",
                         self._all_triggers, why)
                if not self._stopped_within(SAVE_STOP_WAIT_S):
                    log.warning("STG still running %.0f ms after the save stop: immediate "
                                "SendStop", SAVE_STOP_WAIT_S * 1e3)
                    dev.SendStop(self._u32(self._all_triggers))
            else:
                dev.SendStop(self._u32(self._all_triggers))
                log.info("STG SendStop(0x%x) (immediate) sent: %s", self._all_triggers, why)
        except Exception as exc:  # never raise from the safety path
            self._stop_error = (
                f"SendStop failed ({exc}) during {why}: the STG may still be stimulating; "
                "SWITCH THE STIMULATOR OFF at its power switch now, then check the USB cable "
                "and connect again")
            self._stop_failures += 1
            log.critical("STG: %s", self._stop_error)

    def _stopped_within(self, wait_s: float) -> bool:
        """True once no trigger is Running or Armed (``QueryTriggerstatus``), within
        ``wait_s`` of host time; True if this McsUsbNet cannot say."""
        deadline = time.monotonic() + wait_s
        while True:
            try:
                ds = self._query_locked()
            except Exception:  # an unreadable status: let the immediate stop follow
                return False
            if ds is None or not ds.any_active:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.001)

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
        entry = find_stg(api, self.serial)
        dev = api.CStg200xDownloadNet()
        dev.Stg200xPollStatusEvent += self._on_poll
        status = dev.Connect(entry)
        if status not in (None, 0):
            try:
                dev.Dispose()
            except Exception:  # nothing to release on a refused connection
                pass
            raise DeviceError(f"McsUsbNet Connect to STG {entry.SerialNumber} failed with "
                              f"status {status} (is MC_Stimulus II or another program "
                              "connected to it?)")
        self._dev = dev
        try:
            self._io.acquire()
            try:
                self._configure_device(entry)
            finally:
                self._release()  # a stop requested meanwhile is sent here
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
        # SetupRetriggerMode (XML): "The STG has three options how to handle a successive
        # trigger while a trigger is active: stop this trigger (default action), restart
        # this trigger, ignore the signal"; RetriggerActionEnumNet also has Gate and Single,
        # which MC_Stimulus II may have left set. Set to the documented default: a second
        # pulse on Trigger In ends the trial at zero and is reported as an early end.
        stop = api_retrigger_stop(self.api)
        dev.SetupRetriggerMode(stop, stop)
        for ch in (self.ext_ch, self.flex_ch):
            self._range_nA[ch] = float(dev.GetCurrentRangeInNanoAmp(self._u32(ch - 1)))
            self._res_nA[ch] = float(dev.GetCurrentResolutionInNanoAmp(self._u32(ch - 1)))
            range_mA = self._range_nA[ch] / NA_PER_MA
            if self.ceiling_mA[ch] > range_mA:
                raise DeviceRangeError(
                    f"current ceiling {self.ceiling_mA[ch]:g} mA on stimulator channel {ch} "
                    f"exceeds the device's range {range_mA:g} mA; lower the ceiling in the "
                    "hardware config")
        # no SetOutputRate: download mode's resolution is fixed at 20 us (module docstring)
        got = STG4002_OUTPUT_RATE_HZ
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
            dev = self._dev
            if dev is None:
                return
            if self._stop_pending:  # an E-stop is waiting: it goes first, immediately
                self._send_stop_locked("deferred stop at disconnect")
            self._send_stop_locked("disconnect (end of session)", save=True)
            self._dev = None
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
        ext, flex = (ChannelPlan(ch, name, self.ceiling_mA[ch], self._range_nA[ch],
                                 self._res_nA[ch])
                     for ch, name in ((self.ext_ch, "extensor"), (self.flex_ch, "flexor")))
        return ext, flex

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
        self._refuse_after_failed_stop()
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
        # the previous trial's data first, so the segment's available memory is all ours
        for ch in prepared.channels:
            dev.ClearChannelData(self._u32(ch - 1))
        dev.ClearSyncData(self._u32(self.sync_out - 1))
        self._capacity = fit_memory(dev, api, prepared, n_channels=self._n_channels,
                                    n_sync=self._n_sync, sync_out=self.sync_out,
                                    total_bytes=self._memory_bytes)
        check_stop()
        self._setup_trigger()
        for ch, data in prepared.channels.items():
            check_stop()
            dev.PrepareAndSendData(self._u32(ch - 1),
                                   api.Array[api.Int32](data.values_nA.tolist()),
                                   api.Array[api.UInt64](data.durations_us.tolist()),
                                   dest.channeldata_current)
        check_stop()
        sync = prepared.sync
        dev.PrepareAndSendData(self._u32(self.sync_out - 1),
                               api.Array[api.Int32](sync.values_nA.tolist()),
                               api.Array[api.UInt64](sync.durations_us.tolist()),
                               dest.syncoutdata)
        self._usage = read_usage(dev, api, prepared)
        check_stop()

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
        self._refuse_after_failed_stop()
        self._io.acquire()
        try:
            self._poll = None
            self._seen_running = False
            self._foreign_start = False
            self._generation += 1
            # host times bracketing the start: the device starts between them (plus its
            # start delay), so an early end is judged from the first, a late one from the
            # second, and a busy host cannot turn a normal end into a fault
            t_before = self._now()
            self._dev.SendStart(self._u32(1))  # trigger 1 (bit 0)
        except Exception as exc:
            self._state = StimulatorState.ERROR
            self._error = f"SendStart failed: {exc}"
            raise DeviceError(f"STG SendStart failed: {exc}") from exc
        finally:
            self._release()
        self._t_start, self._t_sent = t_before, self._now()
        self._state = StimulatorState.RUNNING

    def _refuse_after_failed_stop(self) -> None:
        if self._stop_error:
            raise SafetyError(f"STG: {self._stop_error}")

    def stop_after_period(self) -> None:
        """An ordinary end or abort: the save stop (never cuts a biphasic carrier period,
        see :meth:`_send_stop_locked`), then the immediate stop if the device still runs.

        For an E-stop use :meth:`stop_now`. Never raises.
        """
        with self._flags:
            self._stop_count += 1
        if self._dev is None:
            return
        if self._io.acquire(timeout=STOP_WAIT_S):
            try:
                self._send_stop_locked("ordinary end / abort", save=True)
            finally:
                self._io.release()
        else:
            self.stop_now()
            return
        if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED,
                           StimulatorState.LOADED):
            self._state = StimulatorState.STOPPED

    def stop_now(self) -> None:
        """The immediate ``SendStop`` on every trigger (E-stop): output at zero at once, even
        mid-pulse. Thread-safe, idempotent, never raises.

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

    def delivery_summary(self) -> dict | None:
        """Charge and current figures of the last download (session file
        ``stimulation_json``), or None before the first load."""
        if self.last_download is None:
            return None
        summary = download_summary(self.last_download, self._capacity or None)
        if self._usage:
            summary["memory_used_bytes"] = dict(self._usage)
        return summary

    def describe(self) -> dict:
        """What ``nmsid probe`` prints (after :meth:`connect`)."""
        caps = self.capabilities()
        return {"model": caps.model, "serial": caps.serial,
                "software": self._software, "hardware": self._hardware,
                "channels": caps.n_channels, "output_rate_Hz": caps.output_rate_Hz,
                "range_mA": {ch: r / NA_PER_MA for ch, r in self._range_nA.items()},
                "resolution_uA": {ch: r / 1000 for ch, r in self._res_nA.items()},
                "memory_MB": self._memory_bytes / 1e6,
                "ceiling_mA": dict(self.ceiling_mA),
                "electrode_off": ELECTRODE_OFF_NOTE}


ELECTRODE_OFF_NOTE = (
    "NOT detected by an STG4002: an open current output drives its output voltage to the "
    "maximum (STG4000 manual 12.5) and no status reports it; check the electrodes before each "
    "sE level (docs/hardware.md, 'Electrode contact')")
"""What ``nmsid probe`` says about electrode-off (Stg5OvercurrentStatusEnumNet is STG5's)."""


def api_retrigger_stop(api):
    """``RetriggerActionEnumNet.Stop`` from the loaded names (the documented default)."""
    return api.RetriggerActionEnumNet.Stop


class _Aborted(Exception):
    """Internal: a stop arrived during a download (turned into StimulatorFault)."""
