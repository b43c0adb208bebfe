"""The physical STG behind the fake McsUsbNet: status per trigger, playback, memory, faults.

See ``testing/fakes/fake_mcs_usb.py`` for the vendor sources of each behaviour. The enums
and ``StgStatusNet`` are those of ``Mcs.Usb`` (values from McsUsbNet 5.3.15's metadata).
"""

from __future__ import annotations

import enum
import threading
import time

import numpy as np


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


class RetriggerActionEnumNet(enum.IntEnum):
    """Values from McsUsbNet 5.3.15's metadata (reflection: Stop 0 .. Single 4)."""

    Stop = 0
    Restart = 1
    Ignore = 2
    Gate = 3
    Single = 4


# "None" is a Python keyword: the functional API (metadata: None 0, UpdateTrigger 1,
# DownloadOnly 2, TriggerOnly 4, SyncStart 8)
Stg200xSegmentFlagsEnumNet = enum.IntEnum(
    "Stg200xSegmentFlagsEnumNet",
    [("None", 0), ("UpdateTrigger", 1), ("DownloadOnly", 2), ("TriggerOnly", 4),
     ("SyncStart", 8)])


class Stg5OvercurrentStatusEnumNet(enum.IntEnum):
    Normal = 0
    Shutdown = 1


class StgStatusNet:
    """Fields as in the metadata: ``TiggerStatus`` (sic), ``ListOfChangedTriggers``,
    ``OvercurrentStatus``."""

    def __init__(self, triggers, overcurrent=Stg5OvercurrentStatusEnumNet.Normal,
                 changed=()):
        self.TiggerStatus = list(triggers)
        self.ListOfChangedTriggers = list(changed)
        self.OvercurrentStatus = overcurrent


_INF = float("inf")
POINT_BYTES = 8  # ASSUMED (the download format's size on the device is not documented)


class _Trigger:
    """Playback state of one trigger input."""

    def __init__(self):
        self.start_t: float | None = None   # SendStart (or a left-over pattern)
        self.run_t: float | None = None     # output began (after the start delay)
        self.length_s = 0.0
        self.stop_t: float | None = None    # SendStop / retrigger
        self.armed = False                  # Single mode: waiting for Trigger In
        self.reset_t: float | None = None   # ResetStatus


class FakeStgHardware:
    """The physical device behind the fake library (one per bench); see module docstring."""

    def __init__(self, *, name="STG4002", serial="4002-0001", n_channels=2, n_sync=2,
                 n_triggers=2, range_nA=16_000_000, resolution_nA=500,
                 memory_bytes=64 * 1024 * 1024, software="1.34", hardware="Rev. B",
                 start_delay_s=0.003, retrigger_mode=RetriggerActionEnumNet.Stop,
                 start_status=Stg200xTriggerStatusEnumNet.Idle, poll_period_s=0.05,
                 overcurrent_after_s=None, clock=None):
        self.name, self.serial = name, serial
        self.n_channels, self.n_sync, self.n_triggers = n_channels, n_sync, n_triggers
        self.range_nA, self.resolution_nA = range_nA, resolution_nA
        self.memory_bytes = memory_bytes
        self.software, self.hardware = software, hardware
        # download mode: fixed 20 us resolution (STG4000 manual p.16; XML PrepareAndSendData
        # "The STG has a resolution of 20 us"); no SetOutputRate in download mode
        self.output_rate_Hz = 50_000
        # SegmentDefine (XML): "On reset, the STG has one segment containing all available
        # memory"; a layout left by another program: segment_bytes (tests)
        self.segment_bytes = [memory_bytes]
        self.segment = 0
        # SetupRetriggerMode: whatever the device holds (MC_Stimulus II may leave Gate or
        # Single); "stop this trigger (default action)" (XML) is only the power-up value
        self.retrigger_mode = RetriggerActionEnumNet(retrigger_mode)
        self.save_stops: list[tuple[float, float]] = []
        """(requested, effective) bench times of each save stop (tests)."""
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
        self.call_delay_after_s: dict[str, float] = {}
        self.on_call: dict[str, object] = {}
        self._busy: list[str] = []
        self._busy_lock = threading.Lock()

    # -- time --------------------------------------------------------------------------
    def now(self) -> float:
        """Bench time (``install`` gives the device the bench's clock), else monotonic."""
        if self.clock is not None:
            return self.clock()
        return time.monotonic()

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
        """A pulse on Trigger In (or the front-panel start button) on ``trigger``.

        While the trigger runs, per the retrigger mode (SetupRetriggerMode, XML): Stop "stop
        this trigger (default action)", Restart "restart this trigger", Ignore "ignore the
        signal". A trigger that is idle starts playing what is loaded (the STG4000 manual:
        the trigger inputs and the Start button start the stimulus without a PC); in Single
        mode an armed trigger starts (ASSUMED from the review: Single "sits Armed").
        """
        t = self.now()
        tr = self.triggers[trigger]
        st = self.status_at(t)[trigger]
        mode = self.retrigger_mode
        if st == Stg200xTriggerStatusEnumNet.Running:
            if mode in (RetriggerActionEnumNet.Stop, RetriggerActionEnumNet.Gate,
                        RetriggerActionEnumNet.Single):
                tr.stop_t = t
            elif mode is RetriggerActionEnumNet.Restart:
                tr.start_t = tr.run_t = t
            return
        if st == Stg200xTriggerStatusEnumNet.Armed and tr.armed:
            tr.armed = False
            tr.run_t = t
            return
        self.start_trigger(trigger, t)

    def start_trigger(self, i: int, t: float) -> None:
        """Start trigger ``i`` at ``t`` (SendStart, Trigger In or the Start button)."""
        tr = self.triggers[i]
        n = 0
        for ch in range(self.n_channels):
            if self.channelmap[i] >> ch & 1:
                n = max(n, len(self.expanded.get(ch, ())))
        for s in range(self.n_sync):
            if self.syncoutmap[i] >> s & 1:
                n = max(n, len(self.sync_expanded.get(s, ())))
        rep = self.repeat[i]
        tr.start_t, tr.run_t = t, t + self.start_delay_s
        tr.length_s = _INF if rep == 0 else n * rep / self.output_rate_Hz
        tr.stop_t = tr.reset_t = None
        tr.armed = False
        if self.retrigger_mode is RetriggerActionEnumNet.Gate:
            # ASSUMED (review, issue 25): output only while the gate input is high; with no
            # gate signal the pattern ends at once
            tr.length_s = 0.0
        elif self.retrigger_mode is RetriggerActionEnumNet.Single:
            # ASSUMED (review, issue 25): sits Armed until a pulse on Trigger In
            tr.armed = True
            tr.run_t = _INF

    def save_stop_marked(self, trigger: int, t: float) -> bool:
        """True if a sync output of ``trigger`` has bit 1 (0x02) set at ``t`` (XML SendStop:
        STOP_OPTION_SAVESTOP "bypasses the stop commands when a syncout ... has bit 1 (0x02)
        set")."""
        tr = self.triggers[trigger]
        if tr.run_t is None or tr.run_t == _INF or t < tr.run_t:
            return False
        k = int(np.floor((t - tr.run_t) * self.output_rate_Hz + 1e-9))
        for s in range(self.n_sync):
            data = self.sync_expanded.get(s)
            if self.syncoutmap[trigger] >> s & 1 and data is not None and len(data):
                kk = k % len(data) if self.repeat[trigger] == 0 else k
                if 0 <= kk < len(data) and int(data[kk]) & 0x02:
                    return True
        return False

    def save_stop_time(self, trigger: int, t: float) -> float:
        """When a save stop requested at ``t`` takes effect: at once, or (ASSUMED reading of
        "bypasses ... while a biphasic stimulation pulse is active") at the first output
        tick whose bit 1 is clear."""
        tr = self.triggers[trigger]
        if tr.run_t is None or not self.save_stop_marked(trigger, t):
            return t
        k0 = int(np.floor((t - tr.run_t) * self.output_rate_Hz + 1e-9))
        for s in range(self.n_sync):
            data = self.sync_expanded.get(s)
            if self.syncoutmap[trigger] >> s & 1 and data is not None and len(data):
                clear = np.flatnonzero((np.asarray(data[k0:]) & 0x02) == 0)
                k = k0 + (int(clear[0]) if len(clear) else len(data) - k0)
                return tr.run_t + k / self.output_rate_Hz
        return t

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
        if tr.run_t is None:
            raise ValueError("a trigger that never ran has no end")
        natural = tr.run_t + tr.length_s
        if tr.stop_t is None:
            return natural
        return min(natural, tr.stop_t if tr.start_t is None else max(tr.stop_t, tr.start_t))

    def status_at(self, t: float) -> list:
        S = Stg200xTriggerStatusEnumNet
        out = []
        for tr in self.triggers:
            if tr.start_t is None:
                out.append(S.Idle)
                continue
            if tr.armed and tr.stop_t is None:
                out.append(S.Armed)
                continue
            end = self._end(tr)
            assert tr.run_t is not None          # _end refuses a trigger that never ran
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
        """Sync output level at bench times ``t``: bit 0 of the sync data (bit 1 is the
        save-stop flag, XML SendStop)."""
        data = self.sync_expanded.get(sync)
        return self._play(None if data is None else np.asarray(data) & 0x01, sync, t, True)

    def memory_used(self) -> int:
        """Bytes of the selected segment in use (POINT_BYTES per point, ASSUMED)."""
        pts = sum(len(v) for v, _ in self.channel_data.values())
        pts += sum(len(v) for v, _ in self.sync_data.values())
        return pts * POINT_BYTES
