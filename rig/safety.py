"""The safety interlock, independent of the protocol code.

* :func:`check_waveform` is the only way to build the
  :class:`nmsid.drivers.interfaces.CheckedWaveform` a stimulator accepts: the envelopes are
  checked against ``min(protocol ceiling, device maximum)`` per channel, so a waveform
  above its ceiling cannot reach a stimulator.
* Rule objects watch the force stream, the acquisition flags, the stimulator status and
  the E-stop; each validates its thresholds in ``__init__``, and each answers one question
  the same way, ``check(observation) -> reason | None``, about an :class:`Observation`
  (what the engine saw at one moment); the interlock holds them in a list and asks each.
* :class:`Interlock` executes a trip: ``stimulator.stop_now()`` FIRST, in the tripping
  thread, then latches (no output can start until :meth:`Interlock.rearm`), then reports
  the trip (logging + the engine's callback, which writes the event and aborts the trial).
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nmsid.drivers.interfaces import (
    CheckedWaveform,
    CurrentLimitError,
    ForceChunk,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.errors import SafetyError

log = logging.getLogger(__name__)


class InterlockTripped(SafetyError):
    """Output was refused or stopped because the interlock is latched."""


def _utc_ms() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


# -- the only path to the stimulator ---------------------------------------------------
def effective_ceilings(ceiling_ext_mA: float, ceiling_flex_mA: float,
                       device_max_mA: float) -> tuple[float, float]:
    """Per-channel ceilings: the protocol's, never above what the device allows."""
    for name, v in (("ceiling_ext_mA", ceiling_ext_mA), ("ceiling_flex_mA", ceiling_flex_mA),
                    ("device_max_mA", device_max_mA)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise CurrentLimitError(f"{name} must be a finite number >= 0, got {v!r}")
    return min(ceiling_ext_mA, device_max_mA), min(ceiling_flex_mA, device_max_mA)


def check_waveform(I_ext_mA, I_flex_mA, *, fs_Hz: float, carrier_Hz: float,
                   ceiling_ext_mA: float, ceiling_flex_mA: float,
                   device_max_mA: float) -> CheckedWaveform:
    """Build the stimulator's waveform, checked against the effective ceilings.

    Parameters
    ----------
    I_ext_mA, I_flex_mA : array_like
        Carrier amplitude envelopes, mA.
    fs_Hz, carrier_Hz : float
        Envelope sample rate and carrier frequency.
    ceiling_ext_mA, ceiling_flex_mA : float
        Protocol ceilings per channel (configuration).
    device_max_mA : float
        The stimulator's maximum current (its capabilities).

    Returns
    -------
    CheckedWaveform

    Raises
    ------
    CurrentLimitError
        If any sample is negative, not finite or above ``min(ceiling, device_max_mA)``;
        nothing is sent.
    """
    ce, cf = effective_ceilings(ceiling_ext_mA, ceiling_flex_mA, device_max_mA)
    return CheckedWaveform(I_ext_mA=np.asarray(I_ext_mA, dtype=float),
                           I_flex_mA=np.asarray(I_flex_mA, dtype=float),
                           fs_Hz=float(fs_Hz), carrier_Hz=float(carrier_Hz),
                           ceiling_ext_mA=ce, ceiling_flex_mA=cf)


# -- rules ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Observation:
    """What the engine saw at one moment; a rule looks at the parts it watches and answers
    None (nothing wrong, or nothing it watches) or the reason to trip.

    Attributes
    ----------
    now_s : float
        The engine's clock, s.
    chunk : ForceChunk or None
        The acquisition's latest chunk (None: none arrived).
    expected_index : int or None
        The sample index the chunk should start at (None: not checked).
    stimulator_status : StimulatorStatus or None
        The stimulator's answer (None: not asked).
    stimulator_unavailable : str or None
        Why the stimulator could not be asked (its exception), when it could not.
    switch_pressed : bool or None
        The hardware E-stop switch (None: not read, or no switch).
    no_samples : bool
        The acquisition was read and gave no samples (the stall watch's moment).
    """

    now_s: float
    chunk: ForceChunk | None = None
    expected_index: int | None = None
    stimulator_status: StimulatorStatus | None = None
    stimulator_unavailable: str | None = None
    switch_pressed: bool | None = None
    no_samples: bool = False


class Rule:
    """An interlock rule: a name, its last verdict and why."""

    name = "rule"

    def __init__(self):
        self.ok = True
        self.detail = "ok"

    def check(self, obs: Observation) -> str | None:
        """The reason to trip on ``obs``, or None."""
        return None

    def _verdict(self, reason: str | None) -> str | None:
        if reason is None:
            return None
        self.ok, self.detail = False, reason
        return reason

    def reset(self) -> None:
        self.ok, self.detail = True, "ok"

    def status(self) -> tuple[bool, str]:
        return self.ok, self.detail


class ForceLimitRule(Rule):
    """Trip when |force| exceeds ``limit_N`` (or is not finite)."""

    name = "force_limit"

    def __init__(self, limit_N: float, quantity: str = "force", unit: str = "N"):
        super().__init__()
        if not (math.isfinite(limit_N) and limit_N > 0):
            raise ValueError(f"force limit must be a finite number > 0 N, got {limit_N!r}")
        self.limit_N = float(limit_N)
        """The limit in the session joint's unit (N, or N m for a torque joint)."""
        self.quantity, self.unit = quantity, unit
        self.detail = f"ok (limit {self.limit_N:g} {self.unit})"

    def check(self, obs: Observation) -> str | None:
        chunk = obs.chunk
        if chunk is None:
            return None
        f = np.asarray(chunk.force_N, dtype=float)
        if f.size == 0:
            return None
        bad = ~np.isfinite(f)
        if bad.any():
            k = int(np.argmax(bad))
            return self._verdict(f"{self.quantity} sample {chunk.start_index + k} is not finite "
                                 f"({f[k]!r}): sensor fault")
        a = np.abs(f)
        k = int(np.argmax(a))
        if a[k] > self.limit_N:
            return self._verdict(f"{self.quantity} {f[k]:.2f} {self.unit} at sample "
                                 f"{chunk.start_index + k} is beyond the limit "
                                 f"+/-{self.limit_N:g} {self.unit}")
        return None

    def reset(self) -> None:
        self.ok, self.detail = True, f"ok (limit {self.limit_N:g} {self.unit})"


class StallRule(Rule):
    """Trip when no samples arrived for ``timeout_s`` (on the engine's clock).

    The limit applied is the longer of ``timeout_s`` and two chunk periods, plus two steps
    of the monotonic clock: :meth:`limit_s`. Samples arrive a chunk at a time (NI's default: 10
    reads a second, a chunk every 100 ms), and on Windows ``time.monotonic`` and queue
    waits move in 15.625 ms steps (Python 3.11/3.12; ``time.get_clock_info``), so a limit
    of one chunk period would trip on a healthy stream (issue 24). The chunk period is the
    duration of the longest chunk seen (samples / ``fs_Hz``), or the one the acquisition
    declares (``chunk_period_s``, given to :meth:`start`), which also covers the first
    chunk.
    """

    name = "sensor_stream"

    def __init__(self, timeout_s: float):
        super().__init__()
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"stall timeout must be a finite number > 0 s, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self._last_s: float | None = None
        self._fs_Hz: float | None = None
        self.chunk_period_s = 0.0
        self.tick_s = 0.0

    def start(self, now_s: float, *, fs_Hz: float | None = None,
              chunk_period_s: float | None = None) -> None:
        """Begin watching (acquisition started at ``now_s``, sampling at ``fs_Hz``)."""
        self._last_s = now_s
        self._fs_Hz = fs_Hz if fs_Hz and fs_Hz > 0 else None
        self.chunk_period_s = float(chunk_period_s or 0.0)
        # the clock's step, asked now: 1/64 s on Windows, about 1 ns on Linux
        self.tick_s = float(time.get_clock_info("monotonic").resolution)

    def stop(self) -> None:
        self._last_s = None

    def feed(self, now_s: float, n_samples: int = 0) -> None:
        self._last_s = now_s
        if self._fs_Hz and n_samples:
            self.chunk_period_s = max(self.chunk_period_s, n_samples / self._fs_Hz)

    def limit_s(self) -> float:
        """The gap that trips: ``max(timeout_s, 2 chunk periods) + 2 clock steps`` (a gap
        read on a stepped clock may read up to one step long at each end)."""
        return max(self.timeout_s, 2 * self.chunk_period_s) + 2 * self.tick_s

    def check(self, obs: Observation) -> str | None:
        """A chunk with samples feeds the watch; a read without samples checks the time
        since the last one."""
        if obs.chunk is not None and obs.chunk.n:
            self.feed(obs.now_s, obs.chunk.n)
            return None
        if not obs.no_samples or self._last_s is None:
            return None
        gap = obs.now_s - self._last_s
        limit = self.limit_s()
        if gap > limit:
            return self._verdict(f"no force samples for {gap * 1000:.0f} ms (limit "
                                 f"{limit * 1000:.0f} ms): stream stalled")
        return None


class AcquisitionFlagsRule(Rule):
    """Trip on the acquisition's overrun / over-range / sensor-fault flags, and on a gap
    in the sample indices (samples lost without a flag)."""

    name = "acquisition"

    def __init__(self, overrun: bool = True, over_range: bool = True,
                 sensor_fault: bool = True):
        super().__init__()
        self.overrun, self.over_range, self.sensor_fault = overrun, over_range, sensor_fault

    def check(self, obs: Observation) -> str | None:
        chunk, expected_index = obs.chunk, obs.expected_index
        if chunk is None:
            return None
        fl = chunk.flags
        what = []
        if fl.overrun and self.overrun:
            what.append("overrun (samples lost)")
        if fl.over_range and self.over_range:
            what.append("over-range (sensor or converter saturated)")
        if fl.sensor_fault and self.sensor_fault:
            what.append("sensor fault")
        if what:
            return self._verdict("acquisition reported " + ", ".join(what)
                                 + (f": {fl.detail}" if fl.detail else "")
                                 + f" at sample {chunk.start_index}")
        if expected_index is not None and chunk.start_index != expected_index and \
                self.overrun:
            return self._verdict(f"sample index jumped from {expected_index} to "
                                 f"{chunk.start_index}: samples lost")
        return None


class StimulatorRule(Rule):
    """Trip when the stimulator reports an error, a disconnect, or cannot be asked."""

    name = "stimulator"

    def check(self, obs: Observation) -> str | None:
        if obs.stimulator_unavailable is not None:  # a driver that cannot answer: a fault
            return self._verdict(f"stimulator status unavailable "
                                 f"({obs.stimulator_unavailable}): disconnected?")
        st = obs.stimulator_status
        if st is None:
            return None
        if st.state is StimulatorState.ERROR or st.error:
            return self._verdict(f"stimulator error: {st.error or st.state.value}")
        if st.state is StimulatorState.DISCONNECTED:
            return self._verdict("stimulator disconnected")
        return None


class EStopRule(Rule):
    """The emergency stop: a software press (any thread) or the hardware switch."""

    name = "estop"

    def __init__(self, has_switch: bool):
        super().__init__()
        self.has_switch = has_switch
        self.detail = "ok (switch released)" if has_switch else "ok (no hardware switch)"
        self.switch_pressed = False

    def check(self, obs: Observation) -> str | None:
        if not obs.switch_pressed:
            return None
        self.switch_pressed = True
        return self._verdict("hardware E-stop switch pressed (or unreadable)")

    def reset(self) -> None:
        super().reset()
        self.detail = "ok (switch released)" if self.has_switch else "ok (no hardware switch)"


@dataclass(frozen=True)
class Trip:
    """One interlock trip: which rule, why, when."""

    rule: str
    detail: str
    utc: str
    perf_s: float
    """``time.perf_counter()`` right after the stimulator was told to stop."""


# -- the interlock ---------------------------------------------------------------------
class Interlock:
    """Trips, latches and re-arms; the gate through which output starts.

    Parameters
    ----------
    cfg : protocols.config.InterlockConfig
        Thresholds.
    stimulator : drivers.interfaces.Stimulator
    estop_input : drivers.interfaces.EStopInput, optional
        The hardware switch; polled by :meth:`start_watcher` at ``cfg.estop_poll_Hz``.
    on_trip : callable(Trip), optional
        Called once per latching trip, in the tripping thread, after output is zero.
    joint : protocols.joints.Joint, optional
        The session's joint: its quantity and unit in the force rule's messages (the
        limit ``cfg.force_limit_N`` is in that unit). None: force in N.
    """

    def __init__(self, cfg, stimulator, *, estop_input=None,
                 on_trip: Callable[[Trip], None] | None = None, joint=None):
        self.cfg = cfg
        self.stimulator = stimulator
        self.estop_input = estop_input
        self.on_trip = on_trip
        # the limit is in the joint's unit (protocols/joints.py); None: the elbow's force
        self.force = ForceLimitRule(cfg.force_limit_N,
                                    *((joint.quantity, joint.unit) if joint else ()))
        self.stall = StallRule(cfg.stall_timeout_s)
        self.flags = AcquisitionFlagsRule(cfg.trip_on_overrun, cfg.trip_on_over_range,
                                          cfg.trip_on_sensor_fault)
        self.stim = StimulatorRule()
        self.estop_rule = EStopRule(estop_input is not None)
        #: Every rule, asked in this order by :meth:`check` (flags before the force: a
        #: flagged chunk's samples are not to be judged as forces)
        self.rules: list[Rule] = [self.flags, self.force, self.stall, self.stim,
                                  self.estop_rule]
        self._by_name: dict[str, Rule] = {r.name: r for r in self.rules}
        self._lock = threading.Lock()
        self._latched = threading.Event()
        self._trip: Trip | None = None
        self._watcher: threading.Thread | None = None
        self._watch_stop = threading.Event()

    # -- state ---------------------------------------------------------------------
    @property
    def latched(self) -> bool:
        return self._latched.is_set()

    @property
    def trip_info(self) -> Trip | None:
        """The trip that latched the interlock (None when clear)."""
        return self._trip

    def status(self) -> dict[str, tuple[bool, str]]:
        """Rule name -> (ok, detail)."""
        out = {r.name: r.status() for r in self.rules}
        t = self._trip
        out["latch"] = (t is None, "clear" if t is None else f"latched by {t.rule}: {t.detail}")
        return out

    # -- tripping ------------------------------------------------------------------
    def _stop_output(self) -> None:
        try:
            self.stimulator.stop_now()
        except Exception:  # the interface says never raises; be sure anyway
            log.exception("stimulator.stop_now() raised")

    def trip(self, rule: str, detail: str) -> Trip:
        """Output to zero (first, in this thread), latch, report. Thread-safe.

        Returns the trip that latched the interlock (the first one if already latched).
        """
        self._stop_output()
        perf = time.perf_counter()
        with self._lock:
            first = self._trip is None
            trip = self._trip if self._trip is not None else \
                Trip(rule, detail, _utc_ms(), perf)
            if first:
                self._trip = trip
                self._latched.set()
            # a start() racing this trip finished before we took the lock: stop again
            self._stop_output()
        if rule in self._by_name and self._by_name[rule].ok:
            self._by_name[rule]._verdict(detail)
        if first:
            # the E-stop is the operator's (or a signal's) own act, reported by the UI that
            # took it; a fault trip is news: a warning
            log.log(logging.INFO if rule == self.estop_rule.name else logging.WARNING,
                    "interlock tripped by %s: %s", rule, detail)
            if self.on_trip is not None:
                try:
                    self.on_trip(trip)
                except Exception:
                    log.exception("interlock on_trip callback failed")
        else:
            log.info("interlock already latched (%s); also: %s: %s", trip.rule, rule, detail)
        return trip

    def estop(self, reason: str = "operator E-stop") -> Trip:
        """The E-stop: callable from any thread."""
        return self.trip(self.estop_rule.name, reason)

    def rearm(self) -> None:
        """Clear the latch (the operator's explicit decision).

        Raises
        ------
        InterlockTripped
            If the hardware E-stop switch is still pressed.
        """
        if self.estop_input is not None and self._switch_pressed():
            raise InterlockTripped("cannot re-arm: the hardware E-stop switch is still "
                                   "pressed (release it first)")
        with self._lock:
            self._trip = None
            self._latched.clear()
            for r in self.rules:
                r.reset()
        log.info("interlock re-armed")

    # -- the gate --------------------------------------------------------------------
    def start_output(self) -> None:
        """Start the loaded waveform, unless latched (atomic with respect to trips).

        Raises
        ------
        InterlockTripped
        """
        with self._lock:
            if self._trip is not None:
                raise InterlockTripped(f"output refused: interlock latched by "
                                       f"{self._trip.rule}: {self._trip.detail}")
            self.stimulator.start()

    # -- the stream watch and the faults a block reports ---------------------------------
    @property
    def stall_timeout_s(self) -> float:
        """How long the force stream may be silent before the interlock trips, s."""
        return self.stall.timeout_s

    def watch_stream(self, now_s: float, *, fs_Hz: float | None = None,
                     chunk_period_s: float | None = None) -> None:
        """Acquisition started at ``now_s``: the stall watch begins (:meth:`StallRule.start`)."""
        self.stall.start(now_s, fs_Hz=fs_Hz, chunk_period_s=chunk_period_s)

    def unwatch_stream(self) -> None:
        """Acquisition stopped: the stall watch ends."""
        self.stall.stop()

    def stimulator_fault(self, detail: str) -> Trip:
        """Trip for a stimulator that failed outside a status check (a refused waveform,
        a driver that raised)."""
        return self.trip(self.stim.name, detail)

    def acquisition_fault(self, detail: str) -> Trip:
        """Trip for an acquisition that failed to start or to read."""
        return self.trip(self.flags.name, detail)

    def stream_stalled(self, detail: str) -> Trip:
        """Trip for a stream found silent by a clock other than the engine's."""
        return self.trip(self.stall.name, detail)

    # -- checks the engine calls -----------------------------------------------------
    def check(self, obs: Observation) -> Trip | None:
        """Ask every rule about ``obs``, in :attr:`rules` order; the first reason trips.

        Returns
        -------
        Trip or None
            The trip that latched the interlock (None: every rule is content).
        """
        for rule in self.rules:
            reason = rule.check(obs)
            if reason:
                return self.trip(rule.name, reason)
        return None

    def check_chunk(self, chunk: ForceChunk, now_s: float,
                    expected_index: int | None = None) -> Trip | None:
        """:meth:`check` of a chunk (flags, index continuity, force; feeds the stall
        watch)."""
        return self.check(Observation(now_s, chunk=chunk, expected_index=expected_index))

    def check_stall(self, now_s: float) -> Trip | None:
        """:meth:`check` of a moment without samples (the stall watch)."""
        return self.check(Observation(now_s, no_samples=True))

    def check_stimulator(self, now_s: float = 0.0) -> Trip | None:
        """Ask the stimulator its status now and :meth:`check` it."""
        try:
            status = self.stimulator.status()
        except Exception as exc:  # a driver that cannot answer is a fault
            return self.check(Observation(now_s, stimulator_unavailable=f"{type(exc).__name__}"
                                                                        f": {exc}"))
        return self.check(Observation(now_s, stimulator_status=status))

    def check_switch(self, now_s: float = 0.0) -> Trip | None:
        """Read the hardware switch now (the engine does it once per chunk, besides the
        watcher thread, so a press is also seen on the engine's own clock)."""
        if self.estop_input is None or not self._switch_pressed():
            return None
        if self._latched.is_set():
            self.estop_rule.switch_pressed = True
            return self._trip
        return self.check(Observation(now_s, switch_pressed=True))

    # -- the hardware switch ---------------------------------------------------------
    def _switch_pressed(self) -> bool:
        try:
            return bool(self.estop_input.is_pressed())
        except Exception:  # fail-safe: an unreadable switch reads as pressed
            return True

    def start_watcher(self) -> None:
        """Poll the hardware switch in a daemon thread (no-op without a switch)."""
        if self.estop_input is None or self._watcher is not None:
            return
        self._watch_stop.clear()
        period_s = 1.0 / self.cfg.estop_poll_Hz
        self._watcher = threading.Thread(target=self._watch, args=(period_s,),
                                         name="nmsid-estop-watcher", daemon=True)
        self._watcher.start()

    def _watch(self, period_s: float) -> None:
        # level-triggered: a pressed (or unreadable) switch keeps the interlock latched
        while not self._watch_stop.is_set():
            pressed = self._switch_pressed()
            self.estop_rule.switch_pressed = pressed
            if pressed and not self._latched.is_set():
                self.trip(self.estop_rule.name, "hardware E-stop switch pressed (or "
                                                "unreadable)")
            time.sleep(period_s)

    def stop_watcher(self) -> None:
        self._watch_stop.set()
        if self._watcher is not None:
            self._watcher.join(timeout=1.0)
            self._watcher = None
