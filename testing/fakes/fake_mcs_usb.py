"""A fake of pythonnet + McsUsbNet: the modules ``clr``, ``System`` and ``Mcs.Usb``.

Built from the vendor's documented behaviour, not from ``drivers.stg4002``. Sources:
McsUsbNet 5.3.15 (``github.com/multichannelsystems/McsUsbNet``): the XML documentation
``x64/McsUsbNet.xml`` ("XML" below) and the type metadata of ``x64/McsUsbNet.dll``
("metadata", read with ``dnfile``); the ``mcs.stg.sdk`` MATLAB wrapper of McsUsbNet
(``cstg200x_download_basic.m``, "wrapper") for ``GetCapacity`` / ``SetCapacity``; pythonnet's
conventions for ``out`` parameters. Where the vendor is silent the behaviour is marked
ASSUMED.

Modelled (each with its source):

* Names and .NET argument types (metadata); ``System.Array[T](items)`` range-checked like
  pythonnet (out-of-range -> ``OverflowError``). Anything not listed raises
  ``AttributeError``.
* ``Stg200xTriggerStatusEnumNet`` Idle 0 / Running 1 / Finished 2 / Armed 3 and
  ``Stg5OvercurrentStatusEnumNet`` Normal 0 / Shutdown 1 (metadata constants); the status
  is kept per trigger ("The STG maintains the status for each of the STG200x_NUM_TRIGGER
  triggers", XML).
* A Running that arrives late: ``SendStart`` "The startup delay is in the range of a few
  ms" (XML); :attr:`FakeStgHardware.start_delay_s` (default 3 ms, tests make it longer);
  during it the trigger reads ``start_status`` (Idle; ASSUMED, Armed selectable).
* Auto-reset: with ``EnableAutoReset`` (the power-up default) "the STG status switches to
  FINISHED only for one poll cycle, after this, it switches to IDLE automatically"; with
  ``DisableAutoReset`` it stays FINISHED until ``ResetStatus(triggermap)`` (XML).
  One poll cycle = :attr:`FakeStgHardware.poll_period_s` (ASSUMED 50 ms).
* A second trigger pulse while a trigger runs stops it (``SetupRetriggerMode``: "stop this
  trigger (default action)", XML): :meth:`FakeStgHardware.trigger_pulse`.
* Overcurrent shutdown (an electrode lost contact): :meth:`FakeStgHardware.lose_contact`
  or ``overcurrent_after_s``; output goes to zero and the status reads Shutdown until
  ``ResetOvercurrent()`` "Reset the Overcurrent Status" (XML; zero output ASSUMED).
* Output rate ``SetOutputRate`` / ``GetOutputRate``, "Valid rates are from 1000 Hz to
  50000 Hz" (XML); the time resolution is one output sample ("The STG has a resolution of
  20 us" at 50 kHz, XML); a rate left by another program persists in the device.
* Memory: ``GetTotalMemory`` (XML); per-channel and per-sync capacities ``GetCapacity`` /
  ``SetCapacity(channelCapacity[], syncCapacity[])`` ("Make sure the sum does not exceed
  the memory", wrapper; "this currently clears both channel and sync memory", wrapper).
  A download larger than its channel's capacity raises the vendor exception mid-download.
  8 bytes per point (ASSUMED; undocumented). ``has_capacity=False`` models McsUsbNet
  5.3.15, whose metadata has no download-mode ``GetCapacity``.
* ``GetStgVersionInfo(out string SwVersion, out string HwVersion)`` is void (metadata):
  pythonnet returns the two out values as ``(sw, hw)``.
* ``SendStop(triggermap)`` stops the triggers in the bitmap only (XML).
* The device keeps playing when the host disconnects or crashes (a pattern left running:
  :meth:`FakeStgHardware.leave_running`); one host connection at a time (ASSUMED: USB
  device opened exclusively; ``Connect`` returns a non-zero status).
* Vendor exceptions (``Mcs.Usb.CUsbExceptionNet``) on an unplugged device, a handle from
  before a replug, and calls after ``Dispose`` (``System.ObjectDisposedException``).
* Concurrency: McsUsbNet does not document its objects as thread-safe; the fake records
  every overlap of two vendor calls on one device in :attr:`FakeStgHardware.overlaps`.

The device plays its downloads on the :class:`~bench.FakeBench` clock so the fake A/D can
sample its sync, the force it evokes and (dry run) the voltage over a dummy-load resistor.
"""

from __future__ import annotations

import enum
import sys
import threading
import time
import types

import numpy as np

POINT_BYTES = 8  # ASSUMED (the download format's size on the device is not documented)


# -- System ------------------------------------------------------------------------
class _NetInt(int):
    MIN, MAX, NAME = 0, 0, ""

    def __new__(cls, value):
        if isinstance(value, float) and not float(value).is_integer():
            raise TypeError(f"cannot convert {value!r} to System.{cls.NAME}")
        v = int(value)
        if not cls.MIN <= v <= cls.MAX:
            raise OverflowError(f"value {v} out of range for System.{cls.NAME}")
        return super().__new__(cls, v)


class Int32(_NetInt):
    MIN, MAX, NAME = -2 ** 31, 2 ** 31 - 1, "Int32"


class UInt32(_NetInt):
    MIN, MAX, NAME = 0, 2 ** 32 - 1, "UInt32"


class UInt64(_NetInt):
    MIN, MAX, NAME = 0, 2 ** 64 - 1, "UInt64"


class NetArray:
    """``System.Array[T]``: a typed, fixed-length array (items range-checked)."""

    def __init__(self, element_type, items):
        self.element_type = element_type
        arr = np.asarray(items.tolist() if isinstance(items, np.ndarray) else list(items))
        if arr.size and arr.dtype.kind not in "iu":
            if arr.dtype.kind != "f" or not np.all(np.mod(arr, 1) == 0):
                raise TypeError(f"non-integer item for System.{element_type.NAME}[]")
        arr = arr.astype(np.int64)
        if arr.size and (int(arr.min()) < element_type.MIN or int(arr.max()) > element_type.MAX):
            raise OverflowError(f"item out of range for System.{element_type.NAME}[]")
        self.values = arr

    def __len__(self):
        return len(self.values)

    def __getitem__(self, i):
        return self.values[i]

    def __iter__(self):
        return iter(self.values.tolist())


class _ArrayFactory:
    def __getitem__(self, element_type):
        return lambda items: NetArray(element_type, items)


def _require(value, kind, what, array=False):
    if kind is UInt32 and not array:
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2 ** 32:
            raise TypeError(f"{what}: expected System.UInt32, got {value!r}")
        return int(value)
    if not isinstance(value, NetArray) or value.element_type is not kind:
        raise TypeError(f"{what}: expected System.{kind.NAME}[], got {type(value).__name__}")
    return value.values


class CUsbExceptionNet(RuntimeError):
    """``Mcs.Usb.CUsbExceptionNet`` as pythonnet raises it."""


class ObjectDisposedException(RuntimeError):
    """``System.ObjectDisposedException``."""


# -- Mcs.Usb enums (metadata constants) ------------------------------------------------
class DeviceEnumNet(enum.Enum):
    MCS_STG_DEVICE = 1
    MCS_DEVICE_USB = 2


class STG_DestinationEnumNet(enum.Enum):
    channeldata_voltage = 0
    channeldata_current = 1
    syncoutdata = 2


class Stg200xTriggerStatusEnumNet(enum.IntEnum):
    Idle = 0
    Running = 1
    Finished = 2
    Armed = 3


class Stg5OvercurrentStatusEnumNet(enum.IntEnum):
    Normal = 0
    Shutdown = 1


class CMcsUsbListEntryNet:
    def __init__(self, device_name, serial):
        self.DeviceName = device_name
        self.SerialNumber = serial


class StgStatusNet:
    """Fields as in the metadata: ``TiggerStatus`` (sic), ``ListOfChangedTriggers``,
    ``OvercurrentStatus``."""

    def __init__(self, triggers, overcurrent=Stg5OvercurrentStatusEnumNet.Normal,
                 changed=()):
        self.TiggerStatus = list(triggers)
        self.ListOfChangedTriggers = list(changed)
        self.OvercurrentStatus = overcurrent


class _Event:
    def __init__(self):
        self.handlers = []

    def __iadd__(self, handler):
        self.handlers.append(handler)
        return self

    def __isub__(self, handler):
        self.handlers.remove(handler)
        return self

    def fire(self, *args):
        for h in list(self.handlers):
            h(*args)


_INF = float("inf")


class _Trigger:
    """Playback state of one trigger input."""

    def __init__(self):
        self.start_t: float | None = None   # SendStart (or a left-over pattern)
        self.run_t: float | None = None     # output began (after the start delay)
        self.length_s = 0.0
        self.stop_t: float | None = None    # SendStop / retrigger
        self.reset_t: float | None = None   # ResetStatus


class FakeStgHardware:
    """The physical device behind the fake library (one per bench); see module docstring."""

    def __init__(self, *, name="STG4002", serial="4002-0001", n_channels=2, n_sync=2,
                 n_triggers=2, range_nA=16_000_000, resolution_nA=500,
                 memory_bytes=64 * 1024 * 1024, software="1.34", hardware="Rev. B",
                 output_rate_Hz=50_000, has_capacity=True, start_delay_s=0.003,
                 start_status=Stg200xTriggerStatusEnumNet.Idle, poll_period_s=0.05,
                 overcurrent_after_s=None, clock=None):
        self.name, self.serial = name, serial
        self.n_channels, self.n_sync, self.n_triggers = n_channels, n_sync, n_triggers
        self.range_nA, self.resolution_nA = range_nA, resolution_nA
        self.memory_bytes = memory_bytes
        self.software, self.hardware = software, hardware
        self.output_rate_Hz = int(output_rate_Hz)
        self.has_capacity = has_capacity
        n = n_channels + n_sync
        self.channel_capacity = [memory_bytes // n] * n_channels   # ASSUMED power-up layout
        self.sync_capacity = [memory_bytes // n] * n_sync
        self.start_delay_s = start_delay_s
        self.start_status = Stg200xTriggerStatusEnumNet(start_status)
        self.poll_period_s = poll_period_s
        self.overcurrent_after_s = overcurrent_after_s
        self.autoreset = True
        self.current_mode = False
        self.plugged = True
        self.plug_generation = 0
        self.opened_by = None
        self.clock = clock
        self.channel_data: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.sync_data: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.expanded: dict[int, np.ndarray] = {}
        self.envelope: dict[int, np.ndarray] = {}
        self.sync_expanded: dict[int, np.ndarray] = {}
        self.trigger_setup = None
        self.channelmap = [0] * n_triggers
        self.syncoutmap = [0] * n_triggers
        self.repeat = [1] * n_triggers
        self.triggers = [_Trigger() for _ in range(n_triggers)]
        self.overcurrent_t: float | None = None
        self.overlaps: list[tuple[str, str]] = []
        self.call_delay_s: dict[str, float] = {}
        self.on_call: dict[str, object] = {}
        self._busy: list[str] = []
        self._busy_lock = threading.Lock()

    # -- time --------------------------------------------------------------------------
    def now(self) -> float:
        bench = _Registry.bench
        if self.clock is not None:
            return self.clock()
        return bench.now() if bench is not None else time.monotonic()

    @property
    def tick_us(self) -> int:
        return int(round(1e6 / self.output_rate_Hz))

    # -- physical events (tests) --------------------------------------------------------
    def unplug(self) -> None:
        self.plugged = False

    def replug(self) -> None:
        """Plug back: handles opened before are dead (they must reconnect)."""
        self.plugged = True
        self.plug_generation += 1
        self.opened_by = None

    def trigger_pulse(self, trigger: int = 0) -> None:
        """A pulse on a trigger input while it runs: "stop this trigger" (default)."""
        t = self.now()
        tr = self.triggers[trigger]
        if self.status_at(t)[trigger] == Stg200xTriggerStatusEnumNet.Running:
            tr.stop_t = t

    def lose_contact(self) -> None:
        """An electrode loses contact: overcurrent shutdown now."""
        self.overcurrent_t = self.now()

    def leave_running(self, trigger: int, channel: int, current_nA: int) -> None:
        """A pattern left running forever by another program (repeat 0) on ``trigger``."""
        tick = self.tick_us
        vals = np.array([current_nA, -current_nA], dtype=np.int64)
        self.channel_data[channel] = (vals, np.array([tick, tick], dtype=np.int64))
        self.expanded[channel] = vals
        self.envelope[channel] = np.abs(vals).astype(float)
        self.channelmap[trigger] |= 1 << channel
        self.repeat[trigger] = 0
        tr = self.triggers[trigger]
        tr.start_t = tr.run_t = self.now() - 1.0
        tr.length_s, tr.stop_t = _INF, None

    # -- status --------------------------------------------------------------------------
    def _oc_time(self) -> float | None:
        tr = self.triggers[0]
        if self.overcurrent_t is None and self.overcurrent_after_s is not None \
                and tr.run_t is not None and tr.stop_t is None:
            at = tr.run_t + self.overcurrent_after_s
            if self.now() >= at:
                self.overcurrent_t = at
        return self.overcurrent_t

    def _end(self, tr: _Trigger) -> float:
        natural = tr.run_t + tr.length_s
        return natural if tr.stop_t is None else min(natural, max(tr.stop_t, tr.start_t))

    def status_at(self, t: float) -> list:
        S = Stg200xTriggerStatusEnumNet
        out = []
        for tr in self.triggers:
            if tr.start_t is None:
                out.append(S.Idle)
                continue
            end = self._end(tr)
            if t < tr.run_t and (tr.stop_t is None or t < tr.stop_t):
                out.append(self.start_status)
            elif t < end:
                out.append(S.Running)
            elif tr.reset_t is not None and tr.reset_t >= end:
                out.append(S.Idle)
            elif self.autoreset and t >= end + self.poll_period_s:
                out.append(S.Idle)
            else:
                out.append(S.Finished)
        return out

    def overcurrent_status(self, t: float | None = None):
        oc = self._oc_time()
        t = self.now() if t is None else t
        return (Stg5OvercurrentStatusEnumNet.Shutdown if oc is not None and t >= oc
                else Stg5OvercurrentStatusEnumNet.Normal)

    def stg_status(self, t: float | None = None) -> StgStatusNet:
        t = self.now() if t is None else t
        return StgStatusNet(self.status_at(t), self.overcurrent_status(t))

    def change_times(self, after: float, until: float) -> list[float]:
        """Times in (after, until] at which some status changes (for the poll events)."""
        pts = []
        for tr in self.triggers:
            if tr.start_t is None:
                continue
            end = self._end(tr)
            pts += [tr.start_t, tr.run_t, end, end + self.poll_period_s]
            pts += [x for x in (tr.stop_t, tr.reset_t) if x is not None]
        oc = self._oc_time()
        if oc is not None:
            pts.append(oc)
        return sorted(p for p in pts if after < p <= until and p != _INF)

    # -- playback (what the bench samples) ---------------------------------------------
    @property
    def started_at(self) -> float | None:
        """Bench time at which trigger 1's output (and its sync) began."""
        return self.triggers[0].run_t

    @property
    def stopped_at(self) -> float | None:
        return self.triggers[0].stop_t

    def _trigger_of(self, channel: int, sync: bool) -> int | None:
        maps = self.syncoutmap if sync else self.channelmap
        for i, m in enumerate(maps):
            if m >> channel & 1:
                return i
        return None

    def _play(self, data: np.ndarray | None, channel: int, t, sync: bool) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        i = self._trigger_of(channel, sync)
        if data is None or i is None or self.triggers[i].run_t is None or not len(data):
            return np.zeros(len(t))
        tr = self.triggers[i]
        k = np.floor((t - tr.run_t) * self.output_rate_Hz + 1e-9).astype(np.int64)
        live = (k >= 0) & (t < self._end(tr))
        if self.repeat[i] == 0:  # repeat forever
            k = np.mod(k, len(data))
        else:
            live &= k < len(data)
        oc = self._oc_time()
        if oc is not None and not sync:
            live &= t < oc
        return np.where(live, data[np.clip(k, 0, len(data) - 1)], 0).astype(np.float64)

    def current_at(self, channel: int, t) -> np.ndarray:
        """Output current (nA) of ``channel`` (0-based) at bench times ``t``."""
        return self._play(self.expanded.get(channel), channel, t, False)

    def envelope_at(self, channel: int, t) -> np.ndarray:
        """Demodulated amplitude (nA): peak |I| over the last carrier period."""
        return self._play(self.envelope.get(channel), channel, t, False)

    def sync_at(self, sync: int, t) -> np.ndarray:
        return self._play(self.sync_expanded.get(sync), sync, t, True)


class _Registry:
    hardware: list[FakeStgHardware] = []
    bench = None
    references: list[str] = []
    devices: list["CStg200xDownloadNet"] = []


class CMcsUsbListNet:
    def __init__(self, device_enum=None):
        if device_enum is not None and not isinstance(device_enum, DeviceEnumNet):
            raise TypeError("CMcsUsbListNet expects a DeviceEnumNet")
        self._entries = [CMcsUsbListEntryNet(h.name, h.serial)
                         for h in _Registry.hardware if h.plugged]

    @property
    def Count(self):
        return UInt32(len(self._entries))

    def GetUsbListEntry(self, index):
        return self._entries[_require(index, UInt32, "GetUsbListEntry index")]


def _vendor(fn):
    """Wrap a vendor method: log it, check the handle, detect overlapping calls."""
    name = fn.__name__

    def call(self, *args):
        self._log(name, *args)
        hw = self.hw
        if hw is not None:
            with hw._busy_lock:
                if hw._busy:
                    hw.overlaps.append((hw._busy[-1], name))
                hw._busy.append(name)
        try:
            if hw is not None:
                hook = hw.on_call.get(name)
                if hook is not None:
                    hook()
                delay = hw.call_delay_s.get(name, 0.0)
                if delay:
                    time.sleep(delay)
            result = fn(self, *args)
            self._fire_if_changed()
            return result
        finally:
            if hw is not None:
                with hw._busy_lock:
                    hw._busy.remove(name)
    call.__name__ = name
    return call


class CStg200xDownloadNet:
    """Fake download-mode STG handle (one host connection to a :class:`FakeStgHardware`)."""

    def __init__(self):
        self.Stg200xPollStatusEvent = _Event()
        self.calls: list[tuple] = []
        self.hw: FakeStgHardware | None = None
        self.disposed = False
        self._generation = -1
        self._last_fired = None
        self._last_t = -_INF
        self.fail_next: dict[str, Exception] = {}
        _Registry.devices.append(self)

    # -- plumbing ----------------------------------------------------------------------
    def _log(self, name, *args):
        if self.disposed:
            raise ObjectDisposedException(f"System.ObjectDisposedException: {name} on a "
                                          "disposed CStg200xDownloadNet")
        self.calls.append((name, *args))
        if name in self.fail_next:
            raise self.fail_next.pop(name)

    def _need(self):
        hw = self.hw
        if hw is None or not hw.plugged or hw.plug_generation != self._generation:
            raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: device not connected")
        return hw

    def _fire_if_changed(self):
        """McsUsbNet's poll thread, run lazily: one event per status change since the last
        call (so a short Running or a one-cycle Finished is reported as it would be)."""
        hw = self.hw
        if hw is None or not hw.plugged or hw.plug_generation != self._generation:
            return
        now = hw.now()
        for t in [*hw.change_times(self._last_t, now), now]:
            st = hw.stg_status(t)
            key = (tuple(st.TiggerStatus), st.OvercurrentStatus)
            if key != self._last_fired:
                self._last_fired = key
                self.Stg200xPollStatusEvent.fire(UInt32(0), st, [])
        self._last_t = now

    def poll(self):
        """What McsUsbNet's poll thread does: fire the event if the status changed."""
        self._fire_if_changed()

    # -- pass-through for tests and the bench --------------------------------------------
    def __getattr__(self, name):
        if name in ("started_at", "stopped_at", "current_at", "envelope_at", "sync_at",
                    "channel_data", "sync_data", "trigger_setup", "current_mode"):
            hw = self.__dict__.get("hw") or self.__dict__.get("_last_hw")
            if hw is None:
                raise AttributeError(name)
            return getattr(hw, name)
        if name in ("_expanded", "_sync_expanded"):
            hw = self.__dict__.get("hw") or self.__dict__.get("_last_hw")
            return getattr(hw, name[1:])
        raise AttributeError(f"'CStg200xDownloadNet' has no attribute {name!r} (not part "
                             "of the fake McsUsbNet)")

    # -- connection ----------------------------------------------------------------------
    @_vendor
    def Connect(self, entry):
        for hw in _Registry.hardware:
            if hw.serial == entry.SerialNumber and hw.plugged:
                owner = hw.opened_by
                if owner is not None and owner is not self and not owner.disposed \
                        and owner.hw is hw and owner._generation == hw.plug_generation:
                    return 1  # ASSUMED: the device is open in another connection
                self.hw = self._last_hw = hw
                self._generation = hw.plug_generation
                hw.opened_by = self
                bench = _Registry.bench
                if bench is not None:
                    bench.stimulator = hw
                return 0
        return 1

    @_vendor
    def Disconnect(self):
        hw = self.hw
        if hw is not None and hw.opened_by is self:
            hw.opened_by = None   # the device keeps playing whatever runs
        self.hw = None

    def Dispose(self):
        self._log("Dispose")
        self.disposed = True

    # -- device information ----------------------------------------------------------------
    @_vendor
    def GetNumberOfAnalogChannels(self):
        return UInt32(self._need().n_channels)

    @_vendor
    def GetNumberOfSyncoutChannels(self):
        return UInt32(self._need().n_sync)

    @_vendor
    def GetNumberOfTriggerInputs(self):
        return UInt32(self._need().n_triggers)

    @_vendor
    def SetCurrentMode(self, *channel):
        self._need().current_mode = True

    @_vendor
    def DisableMultiFileMode(self):
        self._need()

    @_vendor
    def GetCurrentRangeInNanoAmp(self, channel):
        _require(channel, UInt32, "channel")
        return Int32(self._need().range_nA)

    @_vendor
    def GetCurrentResolutionInNanoAmp(self, channel):
        _require(channel, UInt32, "channel")
        return Int32(self._need().resolution_nA)

    @_vendor
    def GetTotalMemory(self):
        return UInt32(self._need().memory_bytes)

    @_vendor
    def GetStgVersionInfo(self, software, hardware):
        hw = self._need()
        return (hw.software, hw.hardware)  # void + 2 out strings, as pythonnet returns it

    @_vendor
    def SetOutputRate(self, rate):
        r = _require(rate, UInt32, "rate")
        if not 1000 <= r <= 50_000:
            raise CUsbExceptionNet(f"Mcs.Usb.CUsbExceptionNet: output rate {r} Hz invalid "
                                   "(valid 1000 .. 50000 Hz)")
        self._need().output_rate_Hz = r

    @_vendor
    def GetOutputRate(self):
        return UInt32(self._need().output_rate_Hz)

    # -- status ----------------------------------------------------------------------------
    @_vendor
    def QueryTriggerstatus(self):
        return self._need().stg_status()

    @_vendor
    def ResetStatus(self, triggermap):
        m = _require(triggermap, UInt32, "triggermap")
        hw = self._need()
        t = hw.now()
        for i, tr in enumerate(hw.triggers):
            if m >> i & 1 and tr.start_t is not None and t >= hw._end(tr):
                tr.reset_t = t

    @_vendor
    def EnableAutoReset(self):
        self._need().autoreset = True

    @_vendor
    def DisableAutoReset(self):
        self._need().autoreset = False

    @_vendor
    def ResetOvercurrent(self):
        hw = self._need()
        hw.overcurrent_t = None
        hw.overcurrent_after_s = None

    # -- memory ----------------------------------------------------------------------------
    @_vendor
    def GetCapacity(self, channel_out, sync_out):
        """void GetCapacity(out UInt32[], out UInt32[]) -> pythonnet's (channel, sync)."""
        hw = self._need()
        if not hw.has_capacity:
            raise AttributeError("'CStg200xDownloadNet' object has no attribute "
                                 "'GetCapacity' (McsUsbNet 5.3.15)")
        return (NetArray(UInt32, hw.channel_capacity), NetArray(UInt32, hw.sync_capacity))

    @_vendor
    def SetCapacity(self, channel_capacity, sync_capacity):
        hw = self._need()
        if not hw.has_capacity:
            raise AttributeError("SetCapacity")
        ch = _require(channel_capacity, UInt32, "channelCapacity", array=True).tolist()
        sy = _require(sync_capacity, UInt32, "syncCapacity", array=True).tolist()
        if len(ch) != hw.n_channels or len(sy) != hw.n_sync:
            raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: one capacity per channel and "
                                   "per sync output")
        if sum(ch) + sum(sy) > hw.memory_bytes:
            raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: capacities exceed the memory")
        hw.channel_capacity, hw.sync_capacity = ch, sy
        # wrapper: "this currently clears both channel and sync memory"
        hw.channel_data.clear(), hw.sync_data.clear(), hw.expanded.clear()
        hw.envelope.clear(), hw.sync_expanded.clear()

    # -- download --------------------------------------------------------------------------
    @_vendor
    def SetupTrigger(self, first_trigger, channelmap, syncoutmap, repeat):
        hw = self._need()
        first = _require(first_trigger, UInt32, "first_trigger")
        maps = [_require(a, UInt32, n, array=True).tolist() for a, n in
                ((channelmap, "channelmap"), (syncoutmap, "syncoutmap"), (repeat, "repeat"))]
        for a in maps:
            if first + len(a) > hw.n_triggers:
                raise CUsbExceptionNet("SetupTrigger: more entries than trigger inputs")
        for k in range(len(maps[0])):
            hw.channelmap[first + k] = maps[0][k]
            hw.syncoutmap[first + k] = maps[1][k]
            hw.repeat[first + k] = maps[2][k]
        hw.trigger_setup = (first, *maps)

    @_vendor
    def ClearChannelData(self, channel):
        ch = _require(channel, UInt32, "channel")
        hw = self._need()
        for d in (hw.channel_data, hw.expanded, hw.envelope):
            d.pop(ch, None)

    @_vendor
    def ClearSyncData(self, sync):
        s = _require(sync, UInt32, "sync")
        hw = self._need()
        hw.sync_data.pop(s, None)
        hw.sync_expanded.pop(s, None)

    @_vendor
    def PrepareAndSendData(self, channel, amplitude, duration, destination):
        hw = self._need()
        ch = _require(channel, UInt32, "channel")
        values = _require(amplitude, Int32, "amplitude", array=True)
        durations = _require(duration, UInt64, "duration", array=True)
        if not isinstance(destination, STG_DestinationEnumNet):
            raise TypeError("destination must be an STG_DestinationEnumNet")
        if len(values) != len(durations):
            raise CUsbExceptionNet("amplitude and duration must have the same length")
        tick = hw.tick_us
        if np.any(durations.astype(np.int64) % tick):
            raise CUsbExceptionNet(f"Mcs.Usb.CUsbExceptionNet: durations must be multiples "
                                   f"of {tick} us at {hw.output_rate_Hz} Hz")
        nbytes = len(values) * POINT_BYTES
        sync = destination is STG_DestinationEnumNet.syncoutdata
        if hw.has_capacity:
            cap = (hw.sync_capacity if sync else hw.channel_capacity)
            if ch < len(cap) and nbytes > cap[ch]:
                raise CUsbExceptionNet(
                    f"Mcs.Usb.CUsbExceptionNet: {nbytes} bytes exceed the capacity "
                    f"{cap[ch]} of {'sync' if sync else 'channel'} {ch}")
        else:
            used = sum(len(v) for v, _ in hw.channel_data.values()) * POINT_BYTES
            if used + nbytes > hw.memory_bytes:
                raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: STG memory full")
        expanded = np.repeat(values, durations.astype(np.int64) // tick)
        if destination is STG_DestinationEnumNet.channeldata_current:
            if not hw.current_mode:
                raise CUsbExceptionNet("channel is not in current mode")
            if ch >= hw.n_channels:
                raise CUsbExceptionNet(f"no channel {ch}")
            if np.abs(values).max(initial=0) > hw.range_nA:
                raise CUsbExceptionNet("amplitude outside the current range")
            hw.channel_data[ch] = (values.copy(), durations.copy())
            hw.expanded[ch] = expanded
            per = max(int(round(hw.output_rate_Hz / 1000.0)), 1)  # demodulate over ~1 ms
            mag = np.abs(expanded)
            padded = np.concatenate([np.full(per - 1, mag[0] if len(mag) else 0), mag])
            hw.envelope[ch] = np.lib.stride_tricks.sliding_window_view(
                padded, per).max(axis=1) if len(mag) else mag
        elif sync:
            if ch >= hw.n_sync:
                raise CUsbExceptionNet(f"no sync output {ch}")
            hw.sync_data[ch] = (values.copy(), durations.copy())
            hw.sync_expanded[ch] = expanded
        else:
            raise CUsbExceptionNet("voltage data sent to a current-mode stimulator")

    # -- start / stop ----------------------------------------------------------------------
    @_vendor
    def SendStart(self, trigger_map):
        m = _require(trigger_map, UInt32, "trigger map")
        hw = self._need()
        t = hw.now()
        for i, tr in enumerate(hw.triggers):
            if not m >> i & 1:
                continue
            n = 0
            for ch in range(hw.n_channels):
                if hw.channelmap[i] >> ch & 1:
                    n = max(n, len(hw.expanded.get(ch, ())))
            for s in range(hw.n_sync):
                if hw.syncoutmap[i] >> s & 1:
                    n = max(n, len(hw.sync_expanded.get(s, ())))
            rep = hw.repeat[i]
            tr.start_t, tr.run_t = t, t + hw.start_delay_s
            tr.length_s = _INF if rep == 0 else n * rep / hw.output_rate_Hz
            tr.stop_t = tr.reset_t = None

    @_vendor
    def SendStop(self, trigger_map):
        m = _require(trigger_map, UInt32, "trigger map")
        hw = self._need()
        t = hw.now()
        for i, tr in enumerate(hw.triggers):
            if m >> i & 1 and tr.start_t is not None and tr.stop_t is None \
                    and t < hw._end(tr):
                tr.stop_t = t


def install(bench=None, hardware=None, modules=None) -> dict:
    """Build the fake ``clr``, ``System``, ``Mcs``, ``Mcs.Usb`` modules.

    Returns the ``{name: module}`` dict; it is also put into ``sys.modules`` unless
    ``modules`` (a dict to fill instead, e.g. for ``monkeypatch.setitem``) is given.
    """
    _Registry.hardware = list(hardware) if hardware is not None else [FakeStgHardware()]
    _Registry.bench = bench
    _Registry.references = []
    _Registry.devices = []
    clr = types.ModuleType("clr")
    clr.AddReference = lambda path: _Registry.references.append(str(path))
    system = types.ModuleType("System")
    system.Array = _ArrayFactory()
    system.Int32, system.UInt32, system.UInt64 = Int32, UInt32, UInt64
    system.ObjectDisposedException = ObjectDisposedException
    mcs = types.ModuleType("Mcs")
    usb = types.ModuleType("Mcs.Usb")
    for cls in (CMcsUsbListNet, CMcsUsbListEntryNet, CStg200xDownloadNet, DeviceEnumNet,
                STG_DestinationEnumNet, StgStatusNet, Stg200xTriggerStatusEnumNet,
                Stg5OvercurrentStatusEnumNet, CUsbExceptionNet):
        setattr(usb, cls.__name__, cls)
    mcs.Usb = usb
    mods = {"clr": clr, "System": system, "Mcs": mcs, "Mcs.Usb": usb}
    target = sys.modules if modules is None else modules
    target.update(mods)
    return mods


def registry() -> _Registry:
    return _Registry
