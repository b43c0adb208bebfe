"""A fake of pythonnet + McsUsbNet: the modules ``clr``, ``System`` and ``Mcs.Usb``.

Only what ``drivers.stg4002`` calls exists, with the vendor's names and .NET argument
types (as in MCS's McsUsbNet examples): ``clr.AddReference``; ``System.Array[T](items)``
for ``Int32``, ``UInt32``, ``UInt64`` (range-checked like pythonnet: an out-of-range item
raises ``OverflowError``); ``Mcs.Usb.CMcsUsbListNet(DeviceEnumNet)``, ``.Count``,
``.GetUsbListEntry(UInt32)``; ``CStg200xDownloadNet`` with ``Stg200xPollStatusEvent +=``,
``Connect``, ``SetCurrentMode``, ``DisableMultiFileMode``, ``GetNumberOfAnalogChannels``,
``GetNumberOfSyncoutChannels``, ``GetNumberOfTriggerInputs``,
``GetCurrentRangeInNanoAmp(UInt32)``, ``GetCurrentResolutionInNanoAmp(UInt32)``,
``GetTotalMemory``, ``GetStgVersionInfo``, ``SetupTrigger``, ``ClearChannelData``,
``ClearSyncData``, ``PrepareAndSendData(UInt32, Int32[], UInt64[], STG_DestinationEnumNet)``,
``SendStart(UInt32)``, ``SendStop(UInt32)``, ``Disconnect``, ``Dispose``. Anything else
raises ``AttributeError`` (a driver calling an unknown method fails the tests).

The fake device records every call (``calls``), keeps what was downloaded, refuses values
outside its current range or not a multiple of 20 us, and plays the download on the
:class:`~bench.FakeBench` clock so the fake A/D can sample its sync and the force it evokes.
"""

from __future__ import annotations

import enum
import sys
import types

import numpy as np


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


# -- Mcs.Usb -----------------------------------------------------------------------
class DeviceEnumNet(enum.Enum):
    MCS_STG_DEVICE = 1
    MCS_DEVICE_USB = 2


class STG_DestinationEnumNet(enum.Enum):
    channeldata_voltage = 0
    channeldata_current = 1
    syncoutdata = 2


class CMcsUsbListEntryNet:
    def __init__(self, device_name, serial):
        self.DeviceName = device_name
        self.SerialNumber = serial


class StgStatusNet:
    def __init__(self, running):
        self.TiggerStatus = [1 if running else 0, 0]  # vendor spelling


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


class FakeStgHardware:
    """The physical device behind the fake library (one per bench)."""

    def __init__(self, *, name="STG4002", serial="4002-0001", n_channels=2, n_sync=2,
                 n_triggers=2, range_nA=16_000_000, resolution_nA=500,
                 memory_bytes=64 * 1024 * 1024, firmware=("1.34", "Rev. B")):
        self.name, self.serial = name, serial
        self.n_channels, self.n_sync, self.n_triggers = n_channels, n_sync, n_triggers
        self.range_nA, self.resolution_nA = range_nA, resolution_nA
        self.memory_bytes = memory_bytes
        self.firmware = firmware
        self.plugged = True


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


class CStg200xDownloadNet:
    """Fake download-mode STG: records calls, plays downloads on the bench clock."""

    TICK_US = 20

    def __init__(self):
        self.Stg200xPollStatusEvent = _Event()
        self.calls: list[tuple] = []
        self.hw: FakeStgHardware | None = None
        self.current_mode = False
        self.channel_data: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.sync_data: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.trigger_setup = None
        self.started_at: float | None = None
        self.stopped_at: float | None = None
        self._expanded: dict[int, np.ndarray] = {}
        self._envelope: dict[int, np.ndarray] = {}
        self._sync_expanded: dict[int, np.ndarray] = {}
        self.fail_next: dict[str, Exception] = {}
        _Registry.devices.append(self)

    def _log(self, name, *args):
        self.calls.append((name, *args))
        if name in self.fail_next:
            raise self.fail_next.pop(name)

    def _need(self):
        if self.hw is None or not self.hw.plugged:
            raise RuntimeError("Mcs.Usb.CUsbExceptionNet: device not connected")

    def Connect(self, entry):
        self._log("Connect", entry.SerialNumber)
        for hw in _Registry.hardware:
            if hw.serial == entry.SerialNumber and hw.plugged:
                self.hw = hw
                bench = _Registry.bench
                if bench is not None:
                    bench.stimulator = self
                return 0
        return 1

    def Disconnect(self):
        self._log("Disconnect")
        self.hw = None

    def Dispose(self):
        self._log("Dispose")

    def GetNumberOfAnalogChannels(self):
        self._need(); self._log("GetNumberOfAnalogChannels")
        return UInt32(self.hw.n_channels)

    def GetNumberOfSyncoutChannels(self):
        self._need(); self._log("GetNumberOfSyncoutChannels")
        return UInt32(self.hw.n_sync)

    def GetNumberOfTriggerInputs(self):
        self._need(); self._log("GetNumberOfTriggerInputs")
        return UInt32(self.hw.n_triggers)

    def SetCurrentMode(self, *channel):
        self._need(); self._log("SetCurrentMode", *channel)
        self.current_mode = True

    def DisableMultiFileMode(self):
        self._need(); self._log("DisableMultiFileMode")

    def GetCurrentRangeInNanoAmp(self, channel):
        self._need(); ch = _require(channel, UInt32, "channel")
        self._log("GetCurrentRangeInNanoAmp", ch)
        return Int32(self.hw.range_nA)

    def GetCurrentResolutionInNanoAmp(self, channel):
        self._need(); ch = _require(channel, UInt32, "channel")
        self._log("GetCurrentResolutionInNanoAmp", ch)
        return Int32(self.hw.resolution_nA)

    def GetTotalMemory(self):
        self._need(); self._log("GetTotalMemory")
        return UInt32(self.hw.memory_bytes)

    def GetStgVersionInfo(self, software, hardware):
        self._need(); self._log("GetStgVersionInfo")
        return (0, *self.hw.firmware)

    def SetupTrigger(self, first_trigger, channelmap, syncoutmap, repeat):
        self._need()
        first = _require(first_trigger, UInt32, "first_trigger")
        maps = [_require(a, UInt32, n, array=True).tolist() for a, n in
                ((channelmap, "channelmap"), (syncoutmap, "syncoutmap"), (repeat, "repeat"))]
        for a in maps:
            if len(a) != self.hw.n_triggers:
                raise ValueError("SetupTrigger arrays must have one entry per trigger input")
        self._log("SetupTrigger", first, *maps)
        self.trigger_setup = (first, *maps)

    def ClearChannelData(self, channel):
        self._need(); ch = _require(channel, UInt32, "channel")
        self._log("ClearChannelData", ch)
        self.channel_data.pop(ch, None)

    def ClearSyncData(self, sync):
        self._need(); s = _require(sync, UInt32, "sync")
        self._log("ClearSyncData", s)
        self.sync_data.pop(s, None)

    def PrepareAndSendData(self, channel, amplitude, duration, destination):
        self._need()
        ch = _require(channel, UInt32, "channel")
        values = _require(amplitude, Int32, "amplitude", array=True)
        durations = _require(duration, UInt64, "duration", array=True)
        if not isinstance(destination, STG_DestinationEnumNet):
            raise TypeError("destination must be an STG_DestinationEnumNet")
        self._log("PrepareAndSendData", ch, len(values), destination.name)
        if len(values) != len(durations):
            raise ValueError("amplitude and duration must have the same length")
        if np.any(durations.astype(np.int64) % self.TICK_US):
            raise ValueError("durations must be multiples of 20 us")
        points = sum(len(v) for v, _ in self.channel_data.values()) + len(values)
        if points * 8 > self.hw.memory_bytes:
            raise RuntimeError("Mcs.Usb.CUsbExceptionNet: STG memory full")
        if destination is STG_DestinationEnumNet.channeldata_current:
            if not self.current_mode:
                raise RuntimeError("channel is not in current mode")
            if ch >= self.hw.n_channels:
                raise ValueError(f"no channel {ch}")
            if np.abs(values).max(initial=0) > self.hw.range_nA:
                raise ValueError("amplitude outside the current range")
            self.channel_data[ch] = (values.copy(), durations.copy())
            self._expanded[ch] = np.repeat(values, durations.astype(np.int64) // self.TICK_US)
            # demodulated envelope: peak |I| over the last carrier period (1 ms = 50 ticks)
            mag = np.abs(self._expanded[ch])
            padded = np.concatenate([np.full(49, mag[0] if len(mag) else 0), mag])
            self._envelope[ch] = np.lib.stride_tricks.sliding_window_view(padded, 50).max(axis=1)
        elif destination is STG_DestinationEnumNet.syncoutdata:
            if ch >= self.hw.n_sync:
                raise ValueError(f"no sync output {ch}")
            self.sync_data[ch] = (values.copy(), durations.copy())
            self._sync_expanded[ch] = np.repeat(values, durations.astype(np.int64) // self.TICK_US)
        else:
            raise ValueError("voltage data sent to a current-mode stimulator")

    def SendStart(self, trigger_map):
        self._need(); m = _require(trigger_map, UInt32, "trigger map")
        self._log("SendStart", m)
        bench = _Registry.bench
        self.started_at = bench.now() if bench is not None else 0.0
        self.stopped_at = None
        self.Stg200xPollStatusEvent.fire(UInt32(1), StgStatusNet(True), [0])

    def SendStop(self, trigger_map):
        m = _require(trigger_map, UInt32, "trigger map")
        self._log("SendStop", m)
        self._need()
        bench = _Registry.bench
        if self.started_at is not None and self.stopped_at is None:
            self.stopped_at = bench.now() if bench is not None else 0.0
        self.Stg200xPollStatusEvent.fire(UInt32(0), StgStatusNet(False), [0])

    # -- playback (used by the bench, not by the driver) --------------------------------
    def _index(self, t: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        if self.started_at is None:
            return np.zeros(len(t), dtype=np.int64), np.zeros(len(t), dtype=bool)
        k = np.floor((t - self.started_at) * 1e6 / self.TICK_US + 1e-9).astype(np.int64)
        live = (k >= 0) & (k < length)
        if self.stopped_at is not None:
            live &= t < self.stopped_at
        return np.clip(k, 0, max(length - 1, 0)), live

    def current_at(self, channel: int, t) -> np.ndarray:
        data = self._expanded.get(channel, np.zeros(1, dtype=np.int64))
        k, live = self._index(t, len(data))
        return np.where(live, data[k], 0)

    def envelope_at(self, channel: int, t) -> np.ndarray:
        data = self._envelope.get(channel, np.zeros(1, dtype=np.int64))
        k, live = self._index(t, len(data))
        return np.where(live, data[k], 0).astype(np.float64)

    def sync_at(self, sync: int, t) -> np.ndarray:
        data = self._sync_expanded.get(sync, np.zeros(1, dtype=np.int64))
        k, live = self._index(t, len(data))
        return np.where(live, data[k], 0).astype(np.float64)


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
    mcs = types.ModuleType("Mcs")
    usb = types.ModuleType("Mcs.Usb")
    for cls in (CMcsUsbListNet, CMcsUsbListEntryNet, CStg200xDownloadNet, DeviceEnumNet,
                STG_DestinationEnumNet, StgStatusNet):
        setattr(usb, cls.__name__, cls)
    mcs.Usb = usb
    mods = {"clr": clr, "System": system, "Mcs": mcs, "Mcs.Usb": usb}
    target = sys.modules if modules is None else modules
    target.update(mods)
    return mods


def registry() -> _Registry:
    return _Registry
