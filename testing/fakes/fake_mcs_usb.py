"""A fake of pythonnet + McsUsbNet: the modules ``pythonnet``, ``clr``, ``System`` and
``Mcs.Usb``.

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
* ``pythonnet.load(runtime)`` (pythonnet 3.x, ``pythonnet/__init__.py``): "After a
  successful call, further invocations will return immediately"; ``set_runtime`` once
  loaded raises ``RuntimeError("The runtime ... has already been loaded")``; a runtime that
  cannot be created raises ``RuntimeError("Failed to create a .NET runtime (netfx) ...")``
  (:attr:`_Registry.runtime_failure`). Faked so that no test starts a real CLR (on Windows
  the real pythonnet would start .NET Framework).
* Concurrency: McsUsbNet does not document its objects as thread-safe; the fake records
  every overlap of two vendor calls on one device in :attr:`FakeStgHardware.overlaps`.

The device plays its downloads on the :class:`~bench.FakeBench` clock so the fake A/D can
sample its sync, the force it evokes and (dry run) the voltage over a dummy-load resistor.
"""

from __future__ import annotations

import sys
import time
import types

import numpy as np

from nmsid.testing.fakes.fake_dotnet import (
    CUsbExceptionNet,
    Int32,
    ObjectDisposedException,
    UInt32,
    UInt64,
    _ArrayFactory,
    _require,
)
from nmsid.testing.fakes.fake_stg_device import (
    _INF,
    POINT_BYTES,
    DeviceEnumNet,
    FakeStgHardware,
    RetriggerActionEnumNet,
    Stg5OvercurrentStatusEnumNet,
    Stg200xSegmentFlagsEnumNet,
    Stg200xTriggerStatusEnumNet,
    STG_DestinationEnumNet,
    StgStatusNet,
)


class CMcsUsbListEntryNet:
    def __init__(self, device_name, serial):
        self.DeviceName = device_name
        self.SerialNumber = serial


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


class _Registry:
    hardware: list[FakeStgHardware] = []
    bench = None
    references: list[str] = []
    devices: list[CStg200xDownloadNet] = []
    #: runtimes pythonnet.load was asked for, and the one loaded (None: not yet)
    runtime_loads: list[str | None] = []
    runtime_loaded: str | None = None
    #: set to make the runtime fail to start (no .NET Framework on the machine)
    runtime_failure: str | None = None


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
            if hw is not None and hw.call_delay_after_s.get(name):
                time.sleep(hw.call_delay_after_s[name])   # the call returns late
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
    # Download mode has no GetCapacity / SetCapacity (members of CStg200xStreamingNet only,
    # real 5.3.15 metadata): the documented members are these.
    @_vendor
    def SegmentSelect(self, segment, segmentflags):
        """XML: "Switchs segment"; flags a Stg200xSegmentFlagsEnumNet."""
        seg = _require(segment, UInt32, "segment")
        if not isinstance(segmentflags, Stg200xSegmentFlagsEnumNet):
            raise TypeError("segmentflags must be a Stg200xSegmentFlagsEnumNet")
        hw = self._need()
        if seg >= len(hw.segment_bytes):
            raise CUsbExceptionNet(f"Mcs.Usb.CUsbExceptionNet: no segment {seg}")
        hw.segment = seg

    @_vendor
    def GetAvailableMemory(self):
        """XML: "the amount of memory available in the currently selected segment ... in
        bytes"; the free bytes (ASSUMED: the stricter reading, data already sent counts)."""
        hw = self._need()
        return UInt32(max(hw.segment_bytes[hw.segment] - hw.memory_used(), 0))

    @_vendor
    def GetMemoryUsageDAC(self, channel):
        """XML: "the memory usage of the current segment and selected analog DAC channel"."""
        ch = _require(channel, UInt32, "Channel")
        hw = self._need()
        return UInt32(len(hw.channel_data.get(ch, ((),))[0]) * POINT_BYTES)

    @_vendor
    def GetMemoryUsageSyncout(self, channel):
        ch = _require(channel, UInt32, "Channel")
        hw = self._need()
        return UInt32(len(hw.sync_data.get(ch, ((),))[0]) * POINT_BYTES)

    @_vendor
    def SetupRetriggerMode(self, *args):
        """Two overloads (metadata): (same_trigger, other_trigger) and (SByte trigger,
        same_trigger, other_trigger); RetriggerActionEnumNet values."""
        acts = args[-2:]
        if len(args) not in (2, 3) or not all(isinstance(a, RetriggerActionEnumNet)
                                              for a in acts):
            raise TypeError("SetupRetriggerMode(RetriggerActionEnumNet same_trigger, "
                            "RetriggerActionEnumNet other_trigger)")
        self._need().retrigger_mode = RetriggerActionEnumNet(acts[0])

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
        if hw.memory_used() + nbytes > hw.segment_bytes[hw.segment]:
            raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: STG memory of the segment "
                                   "full")
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
        for i in range(hw.n_triggers):
            if m >> i & 1:
                hw.start_trigger(i, t)

    @_vendor
    def SendStop(self, trigger_map, options=None):
        """Two overloads (metadata): SendStop(UInt32 triggermap) stops at once;
        SendStop(UInt32 triggermap, Int32 options) with STOP_OPTION_SAVESTOP (0x80)
        "bypasses the stop commands when a syncout ... has bit 1 (0x02) set" (XML)."""
        m = _require(trigger_map, UInt32, "trigger map")
        save = False
        if options is not None:
            if not isinstance(options, Int32) or isinstance(options, bool):
                raise TypeError(f"options: expected System.Int32, got {options!r}")
            save = bool(int(options) & 0x80)
        hw = self._need()
        t = hw.now()
        for i, tr in enumerate(hw.triggers):
            if m >> i & 1 and tr.start_t is not None and tr.stop_t is None \
                    and t < hw._end(tr):
                tr.stop_t = hw.save_stop_time(i, t) if save else t
                tr.armed = False
                if save:
                    hw.save_stops.append((t, tr.stop_t))


def _module(name: str, **attrs: object) -> types.ModuleType:
    """A stand-in module ``name`` holding ``attrs``."""
    module = types.ModuleType(name)
    for key, value in attrs.items():
        setattr(module, key, value)
    return module


def _pythonnet_load(runtime=None, **params) -> None:
    """``pythonnet.load``: a no-op once loaded; else start ``runtime`` or fail."""
    _Registry.runtime_loads.append(runtime)
    if _Registry.runtime_loaded is not None:
        return
    if _Registry.runtime_failure is not None:
        raise RuntimeError(f"Failed to create a .NET runtime ({runtime}) using the "
                           f"parameters {params}.\n{_Registry.runtime_failure}")
    _Registry.runtime_loaded = runtime or "netfx"


def _pythonnet_set_runtime(runtime, **params) -> None:
    if _Registry.runtime_loaded is not None:
        raise RuntimeError(f"The runtime {_Registry.runtime_loaded} has already been loaded")


def install(bench=None, hardware=None, modules=None) -> dict:
    """Build the fake ``pythonnet``, ``clr``, ``System``, ``Mcs``, ``Mcs.Usb`` modules.

    Returns the ``{name: module}`` dict; it is also put into ``sys.modules`` unless
    ``modules`` (a dict to fill instead, e.g. for ``monkeypatch.setitem``) is given.
    """
    _Registry.hardware = list(hardware) if hardware is not None else [FakeStgHardware()]
    _Registry.bench = bench
    for hw in _Registry.hardware:
        if hw.clock is None and bench is not None:
            hw.clock = bench.now
    _Registry.references = []
    _Registry.devices = []
    _Registry.runtime_loads, _Registry.runtime_loaded = [], None
    _Registry.runtime_failure = None
    pythonnet = _module("pythonnet", load=_pythonnet_load, set_runtime=_pythonnet_set_runtime)
    clr = _module("clr", AddReference=lambda path: _Registry.references.append(str(path)))
    system = _module("System", Array=_ArrayFactory(), Int32=Int32, UInt32=UInt32,
                     UInt64=UInt64, ObjectDisposedException=ObjectDisposedException)
    usb = _module("Mcs.Usb", **{cls.__name__: cls for cls in (
        CMcsUsbListNet, CMcsUsbListEntryNet, CStg200xDownloadNet, DeviceEnumNet,
        STG_DestinationEnumNet, StgStatusNet, Stg200xTriggerStatusEnumNet,
        Stg5OvercurrentStatusEnumNet, CUsbExceptionNet, RetriggerActionEnumNet,
        Stg200xSegmentFlagsEnumNet)})
    mcs = _module("Mcs", Usb=usb)
    mods = {"pythonnet": pythonnet, "clr": clr, "System": system, "Mcs": mcs, "Mcs.Usb": usb}
    target = sys.modules if modules is None else modules
    target.update(mods)
    return mods


def registry() -> type[_Registry]:
    return _Registry
