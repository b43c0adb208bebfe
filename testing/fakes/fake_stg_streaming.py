"""A fake of McsUsbNet's ``CStg200xStreamingNet``, built from the McsUsbNet manual's
section 6.3 "Streaming mode" and the XML documentation (5.3.15), not from
``drivers.stg_streaming``.

Modelled (each with its source):

* Constructor ``(UInt32 ringbuffer_size[, dataHandler, errorHandler])``: "the size of the
  ringbuffer in PC memory" (XML), per channel in samples (ASSUMED unit: samples, as
  ``GetDataQueueSpace`` "returns number of data points for which there is space").
* ``GetDataQueueSpace(channel)`` / ``GetSyncoutQueueSpace``: free points of the PC queue;
  ``EnqueueData(channel, Int16[])`` "Sends data to the STG for a given channel", "Returns the
  number of enqueued bytes" (XML); points beyond the free space are not taken (ASSUMED).
* "The values for the analog outputs are 16 bits signed integers. The lower bits are
  truncated according to the resolution of the STG" (manual 6.3): the fake keeps
  ``value & ~(2^k - 1)`` (two's complement truncation) with ``2^k`` Int16 steps per
  device resolution step (``resolution_nA`` of the hardware).
* ``SetOutputRate`` ("maximum of 50 kHz"), ``SetCapacity(UInt32[])`` one STG ring size per
  trigger, "must not exceed the total memory" (manual 6.3), ``SetupTrigger(channelmap,
  syncoutmap, digoutmap, autostart, callback_threshold)`` one entry per trigger (XML),
  ``StartLoop`` / ``StopLoop``, ``SendStart`` / ``SendStop``.
* The STG's own memory: after ``StartLoop`` the library moves the PC queue into the STG's
  ring (the manual's 6.3 example: "Give StartLoop some time" before ``SendStart``);
  ``GetFramesBuffered(trigger)`` "Queries the number of frames currently buffered in STG
  Memory" (XML). ASSUMED, to check on the bench (docs/hardware.md): the transfer begins
  :attr:`transfer_delay_s` (10 ms) after ``StartLoop`` and runs at
  :attr:`transfer_speedup` (4) times the output rate; the ring holds ``SetCapacity``
  bytes / 4 frames (the manual's latency formula, "ringbuffersize in bytes/4"); a frame is
  one output sample of the trigger's channels; ``trigger`` is 0-based.
* Playback: after ``SendStart(1)`` samples play at the output rate on the bench clock FROM
  THE STG'S MEMORY; "When DisableContinousMode is used, the STG stops when it runs out of
  data" (manual 6.3), so a ``SendStart`` before any data reached the STG stops at once;
  with continuous mode (the default, ASSUMED) it outputs zero.
"""

from __future__ import annotations

import types

import numpy as np

from nmsid.testing.fakes import fake_mcs_usb
from nmsid.testing.fakes.fake_dotnet import (
    CUsbExceptionNet,
    Int16,
    NetArray,
    UInt16,
    UInt32,
    _require,
)


def _require_array(value, kind, what):
    if not isinstance(value, NetArray) or value.element_type is not kind:
        raise TypeError(f"{what}: expected System.{kind.NAME}[]")
    return value.values


class CStg200xStreamingNet:
    """Fake streaming-mode handle on a :class:`FakeStgHardware` of ``fake_mcs_usb``."""

    def __init__(self, ringbuffer_size, data_handler=None, error_handler=None):
        self.ring = _require(ringbuffer_size, UInt32, "ringbuffer_size")
        self.calls: list[tuple] = []
        self.hw = None
        self.rate_Hz = 50_000
        self.continuous = True
        self.capacity: list[int] = []
        self.trigger = None
        self.loop = False
        self.queued: dict[int, list[int]] = {}
        self.sync_queued: dict[int, list[int]] = {}
        self.played: dict[int, list[int]] = {}
        self.start_t: float | None = None
        self.stop_t: float | None = None
        self._done = 0
        self.queued_t: dict[int, list[float]] = {}   # when each queued frame was enqueued
        self.loop_t: float | None = None
        self._head = 0                             # frames played since StartLoop
        self.transfer_delay_s = 0.010
        self.transfer_speedup = 4.0
        self.fail_next: dict[str, Exception] = {}
        self.disposed = False
        self._generation = -1
        self._hw_seen = None
        _registry.append(self)

    def _log(self, name, *args):
        self.calls.append((name, *args))
        if name in self.fail_next:
            raise self.fail_next.pop(name)

    def _need(self):
        hw = self.hw
        if hw is not None:
            self._hw_seen = hw
        if hw is None or not hw.plugged:
            raise CUsbExceptionNet("Mcs.Usb.CUsbExceptionNet: device not connected")
        return hw

    # -- connection / device ---------------------------------------------------------------
    def Connect(self, entry):
        self._log("Connect", entry)
        for hw in fake_mcs_usb._Registry.hardware:
            if hw.serial == entry.SerialNumber and hw.plugged:
                owner = hw.opened_by
                if owner is not None and owner is not self and \
                        not getattr(owner, "disposed", False) and owner.hw is hw and \
                        getattr(owner, "_generation", None) == hw.plug_generation:
                    return 1   # ASSUMED (as fake_mcs_usb): open in another connection
                self.hw = hw
                self._generation = hw.plug_generation
                hw.opened_by = self
                bench = fake_mcs_usb._Registry.bench
                if bench is not None:   # the bench's sensor now feels this handle's output
                    bench.stimulator = self
                return 0
        return 1

    def Disconnect(self):
        self._log("Disconnect")
        hw = self.hw
        if hw is not None and hw.opened_by is self:
            hw.opened_by = None
        self.hw = None

    def Dispose(self):
        self._log("Dispose")
        self.disposed = True

    def GetNumberOfAnalogChannels(self):
        self._log("GetNumberOfAnalogChannels")
        return UInt32(self._need().n_channels)

    def GetNumberOfSyncoutChannels(self):
        self._log("GetNumberOfSyncoutChannels")
        return UInt32(self._need().n_sync)

    def GetNumberOfTriggerInputs(self):
        self._log("GetNumberOfTriggerInputs")
        return UInt32(self._need().n_triggers)

    def GetTotalMemory(self):
        self._log("GetTotalMemory")
        return UInt32(self._need().memory_bytes)

    def SetCurrentMode(self, *channel):
        self._log("SetCurrentMode")
        self._need().current_mode = True

    def GetCurrentRangeInNanoAmp(self, channel):
        self._log("GetCurrentRangeInNanoAmp", channel)
        _require(channel, UInt32, "channel")
        return self._need().range_nA

    def GetCurrentResolutionInNanoAmp(self, channel):
        self._log("GetCurrentResolutionInNanoAmp", channel)
        _require(channel, UInt32, "channel")
        return self._need().resolution_nA

    # -- streaming setup --------------------------------------------------------------------
    def SetOutputRate(self, rate):
        self._log("SetOutputRate", rate)
        r = _require(rate, UInt32, "rate")
        if not 1000 <= r <= 50_000:
            raise CUsbExceptionNet("output rate outside 1000 .. 50000 Hz")
        self._need()
        self.rate_Hz = r

    def DisableContinousMode(self):
        self._log("DisableContinousMode")
        self.continuous = False

    def SetCapacity(self, capacity):
        self._log("SetCapacity", capacity)
        cap = _require_array(capacity, UInt32, "dwTriggerCapacity").tolist()
        hw = self._need()
        if len(cap) != hw.n_triggers or sum(cap) > hw.memory_bytes:
            raise CUsbExceptionNet("one capacity per trigger, at most the total memory")
        self.capacity = cap

    def SetupTrigger(self, channelmap, syncoutmap, digoutmap, autostart, threshold):
        self._log("SetupTrigger", channelmap, syncoutmap, digoutmap, autostart, threshold)
        arrays = [_require_array(a, UInt32, n).tolist() for a, n in
                  ((channelmap, "channelmap"), (syncoutmap, "syncoutmap"),
                   (digoutmap, "digoutmap"), (autostart, "autostart"),
                   (threshold, "callback_threshold"))]
        if any(len(a) != self._need().n_triggers for a in arrays):
            raise CUsbExceptionNet("one entry per trigger")
        self.trigger = arrays

    def StartLoop(self):
        self._log("StartLoop")
        self.loop_t = self._need().now()
        self.loop = True
        self._head = 0

    def GetFramesBuffered(self, trigger):
        self._log("GetFramesBuffered", trigger)
        _require(trigger, UInt32, "trigger")
        self._advance()
        hw = self._need()
        return UInt32(self._buffered(self._first_channel(), hw.now()))

    def _ring_frames(self) -> int:
        return (self.capacity[0] // 4) if self.capacity else 4000

    def _chans(self) -> list[int]:
        n = self.hw.n_channels if self.hw is not None else 0
        return [ch for ch in range(n) if self.trigger and self.trigger[0][0] >> ch & 1]

    def _arrival(self, ch: int, limit: int | None = None) -> np.ndarray:
        """When each queued frame of ``ch`` is (or will be) in the STG's memory: not before
        it was enqueued, nor before the transfer that began transfer_delay_s after
        StartLoop reaches it at transfer_speedup x the output rate. ``limit``: only the
        first so many frames (the times never decrease, so a count needs no more)."""
        enq = np.asarray(self.queued_t.get(ch, [])[:limit], dtype=np.float64)
        if self.loop_t is None or not self.loop:
            return np.full(len(enq), np.inf)
        g = self._head + np.arange(len(enq))
        return np.maximum(self.loop_t + self.transfer_delay_s
                          + g / (self.rate_Hz * self.transfer_speedup), enq)

    def _buffered(self, ch: int, now: float) -> int:
        """Frames of ``ch`` in the STG's memory at ``now`` (at most its ring)."""
        ring = self._ring_frames()
        return min(ring, int(np.count_nonzero(self._arrival(ch, ring + 1) <= now)))

    def StopLoop(self):
        self._log("StopLoop")
        self.loop = False

    # -- data ---------------------------------------------------------------------------------
    def _advance(self, now: float | None = None):
        """Play the samples due on the bench clock (at ``now``), each only if its frame had
        reached the STG's memory by its time (else, without continuous mode, the STG stops
        there)."""
        if self.start_t is None or self.hw is None or self.stop_t is not None:
            return
        now = self.hw.now() if now is None else now
        due = int(np.floor((now - self.start_t) * self.rate_Hz))
        new = due - self._done
        if new <= 0:
            return
        take = new
        for ch in self._chans():
            arr = self._arrival(ch, new)
            play = self.start_t + (self._done + np.arange(len(arr))) / self.rate_Hz
            late = np.flatnonzero(arr > play + 1e-12)
            take = min(take, int(late[0]) if len(late) else len(arr))
        for ch in self._chans():
            q, qt = self.queued.setdefault(ch, []), self.queued_t.setdefault(ch, [])
            self.played.setdefault(ch, []).extend(q[:take])
            del q[:take], qt[:take]
        self._head += take
        for q in self.sync_queued.values():
            del q[:take]
        self._done += take
        if take < new and not self.continuous and self.stop_t is None:
            # manual 6.3: without continuous mode the STG stops when it runs out of data
            self.stop_t = self.start_t + self._done / self.rate_Hz

    def GetDataQueueSpace(self, channel):
        self._log("GetDataQueueSpace", channel)
        ch = _require(channel, UInt32, "channel")
        self._advance()
        on_pc = len(self.queued.get(ch, [])) - self._buffered(ch, self._need().now())
        return UInt32(max(self.ring - on_pc, 0))

    def GetSyncoutQueueSpace(self, channel):
        self._log("GetSyncoutQueueSpace", channel)
        ch = _require(channel, UInt32, "channel")
        self._advance()
        return UInt32(max(self.ring - len(self.sync_queued.get(ch, [])), 0))

    def _step(self) -> int:
        hw = self._need()
        lsb = hw.range_nA / 32768
        k = max(0, int(np.ceil(np.log2(max(hw.resolution_nA / lsb, 1.0)) - 1e-12)))
        return 1 << k

    def EnqueueData(self, channel, data):
        self._log("EnqueueData", channel, data)
        ch = _require(channel, UInt32, "channel")
        values = _require_array(data, Int16, "data").astype(np.int64)
        self._advance()
        now = self._need().now()
        space = self.ring - (len(self.queued.get(ch, [])) - self._buffered(ch, now))
        take = values[:max(space, 0)]
        step = self._step()
        truncated = take & ~(step - 1)     # manual 6.3: lower bits truncated
        self.queued.setdefault(ch, []).extend(truncated.tolist())
        self.queued_t.setdefault(ch, []).extend([now] * len(take))
        return UInt32(len(take) * 2)

    def EnqueueSyncout(self, channel, data):
        self._log("EnqueueSyncout", channel, data)
        ch = _require(channel, UInt32, "channel")
        values = _require_array(data, UInt16, "data")
        self._advance()
        self.sync_queued.setdefault(ch, []).extend(values.tolist())
        return UInt32(0)

    def SendStart(self, triggermap):
        self._log("SendStart", triggermap)
        _require(triggermap, UInt32, "triggermap")
        if not self.loop:
            raise CUsbExceptionNet("StartLoop first")
        self.start_t = self._need().now()
        self.stop_t = None
        self._done = 0

    def SendStop(self, triggermap):
        self._log("SendStop", triggermap)
        _require(triggermap, UInt32, "triggermap")
        now = self._need().now()
        self._advance(now)     # one instant for both: no thread switch between them counts
        if self.start_t is not None and self.stop_t is None:
            self.stop_t = now

    # -- what the bench sees -------------------------------------------------------------------
    def output_at(self, channel: int) -> np.ndarray:
        """Everything played on ``channel`` (0-based) so far, Int16 values."""
        self._advance()
        return np.asarray(self.played.get(channel, []), dtype=np.int64)

    # -- what the bench's sensor and A/D see (FakeBench.stimulator) ---------------------------
    demod_window_s = 0.002
    """The bench's demodulator: peak of |I| over the last 2 ms (two periods of the 1 kHz
    default carrier; a property of the fake sensor chain, not of the STG)."""

    @property
    def started_at(self) -> float | None:
        """Bench time of ``SendStart`` (the sync's rising edge)."""
        return self.start_t

    @property
    def stopped_at(self) -> float | None:
        return self.stop_t

    def _range_nA(self) -> float:
        hw = self.hw or self._hw_seen
        return float(hw.range_nA) if hw is not None else 0.0

    def _samples_at(self, values: list, t) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        if self.hw is not None:
            self._advance()
        if self.start_t is None or not values:
            return np.zeros(len(t), dtype=np.int64), np.zeros(len(t), dtype=bool)
        k = np.floor((t - self.start_t) * self.rate_Hz + 1e-9).astype(np.int64)
        live = (k >= 0) & (k < len(values))
        if self.stop_t is not None:
            live &= t < self.stop_t
        if not live.any():
            return np.zeros(len(t), dtype=np.int64), live
        lo, hi = int(k[live].min()), int(k[live].max())
        arr = np.asarray(values[lo:hi + 1], dtype=np.int64)
        return np.where(live, arr[np.clip(k - lo, 0, len(arr) - 1)], 0), live

    def current_at(self, channel: int, t) -> np.ndarray:
        """Output current (nA) of ``channel`` (0-based) at bench times ``t``: the played
        Int16 values x range / (2^15 - 1) (manual 6.3's full scale)."""
        v, _ = self._samples_at(self.played.get(channel, []), t)
        return v * self._range_nA() / 32767.0

    def envelope_at(self, channel: int, t) -> np.ndarray:
        """Demodulated amplitude (nA): peak |I| over the last :data:`demod_window_s`."""
        t = np.asarray(t, dtype=np.float64)
        w = max(1, int(round(self.demod_window_s * self.rate_Hz)))
        offs = np.arange(w) / self.rate_Hz
        cur = np.abs(self.current_at(channel, (t[:, None] - offs[None, :]).ravel()))
        return cur.reshape(len(t), w).max(axis=1) if len(t) else np.zeros(0)

    def sync_at(self, sync: int, t) -> np.ndarray:
        """Sync level: high while streamed samples play (the enqueued sync is all ones)."""
        _, live = self._samples_at(self.played.get(self._first_channel(), []), t)
        return live.astype(np.float64)

    def _first_channel(self) -> int:
        hw = self.hw or self._hw_seen
        n = hw.n_channels if hw is not None else 0
        for ch in range(n):
            if self.trigger and self.trigger[0][0] >> ch & 1:
                return ch
        return 0

    @property
    def running(self) -> bool:
        self._advance()
        return self.start_t is not None and self.stop_t is None


_registry: list[CStg200xStreamingNet] = []


def install(modules: dict) -> types.ModuleType:
    """Add ``CStg200xStreamingNet`` (and System.Int16 / UInt16) to fake modules installed
    by ``fake_mcs_usb.install``; returns ``Mcs.Usb``."""
    _registry.clear()
    usb = modules["Mcs.Usb"]
    usb.CStg200xStreamingNet = CStg200xStreamingNet
    system = modules["System"]
    system.Int16, system.UInt16 = Int16, UInt16
    return usb


def registry() -> list[CStg200xStreamingNet]:
    return _registry
