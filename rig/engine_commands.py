"""The engine's operator side: thread-safe commands, their queue, trips and pauses.

A mixin of :class:`nmsid.rig.engine.Engine`. The commands (:meth:`estop`, :meth:`pause`,
...) are callable from any thread: the E-stop acts in the calling thread (output to zero,
latch); the others are queued and executed by the engine thread at its next check
(:meth:`_poll`, between chunks, during rests and waits). Trips and pauses are handled
here between steps (:meth:`_check_interrupts`).
"""

from __future__ import annotations

import enum
import logging
import queue
import threading
from typing import TYPE_CHECKING

from nmsid.protocols.schedule import TrialStatus
from nmsid.protocols.session_file import Calibration
from nmsid.rig.observer import TripPolicy
from nmsid.rig.safety import InterlockTripped, Trip
from nmsid.rig.session_log import utc_now_ms
from nmsid.rig.states import State

if TYPE_CHECKING:  # the engine this mixes into (nmsid.rig.engine imports this module)
    from nmsid.drivers.interfaces import RigDevices
    from nmsid.protocols.config import Config
    from nmsid.protocols.schedule import PlannedTrial
    from nmsid.rig.observer import EngineObserver
    from nmsid.rig.safety import Interlock
    from nmsid.rig.session_log import SessionLog
    from nmsid.rig.states import StateMachine

log = logging.getLogger("nmsid.rig.engine")

#: Longest engine wait between command checks, in real seconds (waits for the operator).
WAIT_SLICE_S = 0.02

class _Cmd(enum.Enum):
    PAUSE = "pause"
    RESUME = "resume"
    ABORT = "abort"
    SKIP = "skip"
    RERUN = "rerun"
    REPEAT = "repeat"
    REARM = "rearm"
    CONFIRM = "confirm"
    NOTE = "note"
    TRIPPED = "tripped"


class _EndRun(Exception):
    """Internal: leave the run loop (abort, or trip under END_SESSION)."""


class OperatorCommands:
    """Commands, their queue and the handling of trips and pauses (engine mixin)."""

    # what it uses of the engine (set by :class:`nmsid.rig.engine.Engine`)
    config: Config
    devices: RigDevices
    interlock: Interlock
    observer: EngineObserver
    schedule: list[PlannedTrial]
    trip_policy: TripPolicy
    calibration: Calibration | None
    _log: SessionLog | None
    _sm: StateMachine
    _cmds: queue.SimpleQueue
    _wake: threading.Event
    _pending_events: list[tuple[str, str, str]]
    _confirmations: list[Calibration]
    _rerun_first: list[int]
    _levels_reported: set[float]
    _pause_req: bool
    _resume_req: bool
    _abort_req: bool
    _abort_by: str
    _skip_req: bool
    _rearm_req: bool

    if TYPE_CHECKING:
        def _stop_output(self) -> None:
            raise NotImplementedError

    # -- public state ----------------------------------------------------------------
    @property
    def state(self) -> State:
        return self._sm.state

    def interlock_status(self) -> dict[str, tuple[bool, str]]:
        """Rule name -> (ok, detail), plus ``latch``."""
        return self.interlock.status()

    # -- commands (any thread) ---------------------------------------------------------
    def estop(self, reason: str = "operator E-stop") -> None:
        """Output to zero now, in the calling thread, and latch the interlock."""
        self.interlock.estop(reason)
        self._wake.set()

    def _put(self, cmd: _Cmd, arg=None) -> None:
        self._cmds.put((cmd, arg))
        self._wake.set()

    def rearm(self) -> None:
        """Clear the latch after a trip (refused, with an event, while the hardware
        switch is pressed); the session continues with the next pending trial."""
        self._put(_Cmd.REARM)

    def pause(self) -> None:
        """Pause: the running trial finishes or is aborted (``protocol.pause_policy``),
        then output stays off until :meth:`resume`."""
        self._put(_Cmd.PAUSE)

    def resume(self) -> None:
        """Leave ``paused``."""
        self._put(_Cmd.RESUME)

    def abort(self, by: str = "operator") -> None:
        """End the session: the running trial is aborted, output off, file closed cleanly
        (it can be resumed later). ``by`` names who asked (the session's end record says
        ``aborted by <by>``), e.g. ``"SIGTERM received"`` for a signal."""
        self._put(_Cmd.ABORT, str(by))

    def skip_trial(self) -> None:
        """Abort the running trial ("skipped by operator"), or between trials mark the
        next pending one aborted without running it."""
        self._put(_Cmd.SKIP)

    def rerun(self, schedule_index: int) -> None:
        """Put an aborted trial back to pending; it runs next (refused, with an event,
        for a trial that is not aborted)."""
        self._put(_Cmd.RERUN, int(schedule_index))

    def repeat_trial(self, schedule_index: int, reason: str) -> None:
        """Run a completed trial once more (e.g. the quality control excluded it while the
        participant is still there); it runs next. The recorded trial stays in the file
        and the new attempt is written as a new trial. Refused (event ``repeat_refused``)
        for a trial that is not completed."""
        self._put(_Cmd.REPEAT, (int(schedule_index), str(reason)))

    def confirm_calibration(self, calibration: Calibration) -> None:
        """The operator's calibration (the measured one, or edited values); used when
        ``calibration.confirm`` is set. Refused (event ``calibration_refused``) if it
        breaks the contract or a current ceiling; the engine then keeps waiting."""
        self._put(_Cmd.CONFIRM, calibration)

    def add_note(self, text: str) -> None:
        """An operator note, written to the session's events (kind ``note``)."""
        self._put(_Cmd.NOTE, str(text))

    # -- internals: events, transitions, commands ---------------------------------------
    def _event(self, kind: str, detail: str = "") -> None:
        if self._log is None:
            self._pending_events.append((utc_now_ms(), kind, detail))
            return
        ev = self._log.event(kind, detail)
        try:
            self.observer.on_event(ev)
        except Exception:
            log.exception("observer.on_event failed")

    def _on_transition(self, old: State, new: State, reason: str) -> None:
        self._event("state", f"{old.value} -> {new.value}" + (f": {reason}" if reason else ""))
        self._notify("on_state", old, new, reason)

    def _notify(self, name: str, *args) -> None:
        try:
            getattr(self.observer, name)(*args)
        except Exception:  # a broken observer must not stop the session
            log.exception("observer.%s failed", name)

    def _on_trip(self, trip: Trip) -> None:
        # any thread: hand it to the engine thread
        self._put(_Cmd.TRIPPED, trip)

    def _poll(self) -> None:
        while True:
            try:
                cmd, arg = self._cmds.get_nowait()
            except queue.Empty:
                break
            if cmd is _Cmd.TRIPPED:
                self._event("interlock_trip", f"{arg.rule}: {arg.detail}")
            elif cmd is _Cmd.PAUSE:
                self._pause_req, self._resume_req = True, False
                self._event("pause_requested", f"policy: {self.config.protocol.pause_policy.value}")
            elif cmd is _Cmd.RESUME:
                self._resume_req = True
            elif cmd is _Cmd.ABORT:
                if not self._abort_req:
                    self._abort_by = arg or "operator"
                self._abort_req = True
                self._event("abort_requested", arg or "operator")
            elif cmd is _Cmd.SKIP:
                self._skip_req = True
            elif cmd is _Cmd.REARM:
                self._rearm_req = True
            elif cmd is _Cmd.CONFIRM:
                self._confirmations.append(arg)
            elif cmd is _Cmd.NOTE:
                self._event("note", arg)
            elif cmd is _Cmd.RERUN:
                self._queue_rerun(arg)
            elif cmd is _Cmd.REPEAT:
                self._queue_repeat(*arg)

    def _queue_rerun(self, index: int) -> None:
        self._queue_again(index, TrialStatus.ABORTED, "rerun", "only aborted trials are re-run")

    def _queue_repeat(self, index: int, reason: str) -> None:
        self._queue_again(index, TrialStatus.DONE, "repeat",
                          "only completed trials are repeated", reason)

    def _queue_again(self, index: int, required: TrialStatus, kind: str, rule: str,
                     reason: str = "") -> None:
        """Put a trial back to pending (it runs next) if its status is ``required``;
        otherwise log ``<kind>_refused``."""
        if not 0 <= index < len(self.schedule):
            self._event(f"{kind}_refused", f"no schedule index {index}")
            return
        pt = self.schedule[index]
        if pt.status is not required:
            self._event(f"{kind}_refused", f"schedule index {index} is {pt.status.value}, "
                                           f"{rule}")
            return
        pt.status, pt.reason = TrialStatus.PENDING, ""
        self._rerun_first.append(index)
        self._levels_reported.discard(round(pt.sE, 9))
        self._event(f"{kind}_queued", f"schedule index {index} (sE {pt.sE:g}, repeat "
                                      f"{pt.repeat})" + (f": {reason}" if reason else ""))

    def _wait_operator(self, until, what: str) -> None:
        """Wait (real time, output off) until ``until()`` is true; abort ends the run."""
        log.info("waiting for the operator: %s", what)
        while True:
            self._poll()
            if self._abort_req:
                raise _EndRun(f"aborted by {self._abort_by}")
            if until():
                return
            self._wake.wait(WAIT_SLICE_S)
            self._wake.clear()

    # -- trips, pauses ---------------------------------------------------------------
    def _check_interrupts(self, *, calibrating: bool = False) -> bool:
        """Between steps: handle abort, trip and pause. Returns True if the caller must
        redo its step (after re-arm / resume)."""
        self._poll()
        if self._abort_req:
            raise _EndRun(f"aborted by {self._abort_by}")
        redo = False
        if self.interlock.latched:
            self._handle_trip(calibrating)
            redo = True
        if self._pause_req:
            self._handle_pause(calibrating)
            redo = True
        return redo

    def _handle_trip(self, calibrating: bool) -> None:
        trip = self.interlock.trip_info
        reason = f"{trip.rule}: {trip.detail}" if trip else "interlock latched"
        self._poll()
        self._sm.to(State.TRIPPED, reason)
        if self.trip_policy is TripPolicy.END_SESSION:
            raise _EndRun(f"interlock: {reason}")
        self._rearm_req = False
        while True:
            self._wait_operator(lambda: self._rearm_req, "re-arm after " + reason)
            self._rearm_req = False
            try:
                self.interlock.rearm()
            except InterlockTripped as exc:
                self._event("rearm_refused", str(exc))
                continue
            break
        if trip is not None and trip.rule == self.interlock.stim.name:
            try:  # a stimulator that reported an error or vanished must reconnect
                self.devices.stimulator.connect()
                self._event("stimulator_reconnected", "after " + reason)
            except Exception as exc:
                self.interlock.trip(self.interlock.stim.name,
                                    f"reconnect failed ({type(exc).__name__}: {exc})")
                return self._handle_trip(calibrating)
        self._event("rearmed", f"operator re-armed after {reason}")
        self._sm.to(State.CALIBRATING if calibrating else State.ARMED, "re-armed")

    def _handle_pause(self, calibrating: bool) -> None:
        self._stop_output()
        self._sm.to(State.PAUSED, "operator")
        self._resume_req = False
        self._wait_operator(lambda: self._resume_req or self.interlock.latched, "resume")
        self._pause_req = self._resume_req = False
        if self.interlock.latched:
            self._handle_trip(calibrating)
            return
        self._sm.to(State.CALIBRATING if calibrating else State.ARMED, "resumed")
        self._event("resumed", "operator")
