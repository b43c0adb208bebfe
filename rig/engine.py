"""The protocol engine: runs calibration and the trial schedule on a rig, safely, logged.

The engine executes the pure protocols (:mod:`nmsid.protocols`) through the device interfaces
(:mod:`nmsid.drivers.interfaces`). Every waveform passes :func:`nmsid.rig.safety.check_waveform`;
every output start passes the :class:`nmsid.rig.safety.Interlock` gate; every trip stops output
first, in the tripping thread. Every trial is written through :class:`rig.session_log.
SessionLog` (journal first, then HDF5).

Threads: :meth:`Engine.run` blocks (the GUI calls it in a worker thread); the commands
(:meth:`estop`, :meth:`pause`, ...) are thread-safe and callable from any thread. The
E-stop acts in the calling thread (output to zero, latch); the other commands are queued
and executed by the engine thread at its next check (between chunks, during rests and
waits). Observer callbacks run in the engine thread.
"""

from __future__ import annotations

import enum
import logging
import math
import queue
import secrets
import threading
from pathlib import Path

import numpy as np

from nmsid.drivers.interfaces import RigDevices
from nmsid.protocols.config import Config, ConfigError, PausePolicy, config_from_json
from nmsid.protocols.schedule import (PlannedTrial, TrialStatus, make_schedule, schedule_from_json,
                                      schedule_to_json)
from nmsid.protocols.waveforms import input_attrs, trial_waveform
from nmsid.rig.engine_calibration import CalibrationSteps
from nmsid.rig.observer import (RERUN_WAIT_PREFIX, EngineObserver, RunSummary, TripPolicy,
                                is_rerun_wait, rerun_wait_reason)
from nmsid.rig.safety import Interlock, InterlockTripped, Trip, check_waveform
from nmsid.protocols.session_file import Calibration, SessionExistsError, Trial, utc_now
from nmsid.rig.session_log import SessionLog, journal_dir, load_trial_npz, utc_now_ms
from nmsid.rig.states import State, StateMachine
from nmsid.rig.stimulation import BlockResult, run_block

__all__ = ["Engine", "EngineObserver", "RunSummary", "TripPolicy", "RERUN_WAIT_PREFIX",
           "is_rerun_wait", "rerun_wait_reason"]

log = logging.getLogger(__name__)

#: Longest engine wait between command checks, in real seconds (waits for the operator).
WAIT_SLICE_S = 0.02
#: Rest is slept in slices of this many engine-clock seconds, checking commands between.
REST_SLICE_S = 0.05


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


class Engine(CalibrationSteps):
    """Runs one session.

    Parameters
    ----------
    config : protocols.config.Config or None
        The validated configuration (ignored with ``resume``: the session's stored one is
        used). A missing seed is drawn now and recorded.
    devices : drivers.interfaces.RigDevices
    session_path : path-like
        The HDF5 file to write (must not exist), or to continue with ``resume``.
    resume : bool
        Continue the session in ``session_path``: recover it first if needed, skip its
        completed trials and re-run its aborted ones.
    observer : EngineObserver, optional
    trip_policy : TripPolicy
        ``WAIT_FOR_REARM`` (default, an operator is present) or ``END_SESSION``.
    extra_attrs : dict, optional
        Additional root attributes of a new session file (e.g. ``sim_seed``).
    """

    def __init__(self, config: Config | None, devices: RigDevices, session_path, *,
                 resume: bool = False, observer: EngineObserver | None = None,
                 trip_policy: TripPolicy = TripPolicy.WAIT_FOR_REARM,
                 extra_attrs: dict | None = None):
        self.devices = devices
        self.clock = devices.clock
        self.path = Path(session_path)
        self.observer = observer or EngineObserver()
        self.trip_policy = trip_policy
        self.resume_mode = resume
        self.extra_attrs = dict(extra_attrs or {})
        self.recovery = None
        self._log: SessionLog | None = None
        self._cmds: queue.SimpleQueue = queue.SimpleQueue()
        self._wake = threading.Event()
        self._sm = StateMachine(self._on_transition)
        self._pending_events: list[tuple[str, str, str]] = []
        self._trials_this_run: dict[int, Trial] = {}
        self._levels_reported: set[float] = set()
        self._ran = False
        # operator flags (engine thread only)
        self._pause_req = self._resume_req = self._abort_req = False
        self._skip_req = self._rearm_req = False
        self._confirmations: list[Calibration] = []
        self._rerun_first: list[int] = []
        self.calibration: Calibration | None = None
        if resume:
            self._log, self.recovery = SessionLog.resume(self.path)
            header = self._log.header
            self.config = config_from_json(header["config_json"], source=f"{self.path} "
                                           "(stored configuration)")
            self.seed = header.get("seed")
            self.schedule = schedule_from_json(header["extra_attrs"]["schedule_json"])
            self.calibration = self._log.calibration
            self._restore_statuses()
        else:
            if config is None:
                raise ValueError("Engine needs a configuration for a new session")
            if self.path.exists() or journal_dir(self.path).exists():
                raise SessionExistsError(self.path)
            seed = config.seed if config.seed is not None else secrets.randbelow(2 ** 31)
            self.config = config.replace(seed=seed) if config.seed is None else config
            self.seed = seed
            p = self.config.protocol
            self.schedule = make_schedule(p.sE_levels, p.repeats, p.randomisation, seed)
        self.interlock = Interlock(self.config.interlock, devices.stimulator,
                                   estop_input=devices.estop, on_trip=self._on_trip)

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

    def abort(self) -> None:
        """End the session: the running trial is aborted, output off, file closed cleanly
        (it can be resumed later)."""
        self._put(_Cmd.ABORT)

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
                self._abort_req = True
                self._event("abort_requested", "operator")
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
                raise _EndRun("aborted by operator")
            if until():
                return
            self._wake.wait(WAIT_SLICE_S)
            self._wake.clear()

    # -- the run -----------------------------------------------------------------------
    def run(self) -> RunSummary:
        """Calibrate (unless known), then run the schedule. Blocks until done.

        Raises
        ------
        ConfigError
            If the configuration does not fit the devices (before anything is stimulated).
        CalibrationError
            If calibration failed and no operator can enter the currents.
        """
        if self._ran:
            raise RuntimeError("an Engine runs once; make a new one to resume")
        self._ran = True
        t0 = self.clock.monotonic_s()
        ended_by = "schedule complete"
        journal_removed = False
        error: BaseException | None = None
        try:
            self._setup()
            self._calibrate()
            self._run_schedule()
        except _EndRun as exc:
            ended_by = str(exc)
        except BaseException as exc:  # includes KeyboardInterrupt: still leave output zero
            error = exc
            ended_by = f"error: {type(exc).__name__}: {exc}"
            self.interlock.trip("engine", ended_by)
        finally:
            self._stop_output()
            self.interlock.stop_watcher()
            try:
                self.devices.acquisition.stop()
            except Exception:
                log.exception("acquisition.stop() failed")
            if self.state is not State.FINISHED:
                self._sm.to(State.FINISHED, ended_by)
            if self._log is not None:
                self._event("session_end", ended_by)
                if error is None:
                    journal_removed = self._log.finish()
                else:
                    if self._log.calibration is not None:
                        self._log.flush_events()
                    self._log.close()
            self._notify("on_finished", str(self.path))
        summary = self._summary(ended_by, journal_removed, self.clock.monotonic_s() - t0)
        if error is not None:
            raise error
        return summary

    def _summary(self, ended_by: str, journal_removed: bool, dt: float) -> RunSummary:
        st = [t.status for t in self.schedule]
        return RunSummary(
            path=self.path, final_state=self.state, ended_by=ended_by,
            n_completed=st.count(TrialStatus.DONE), n_aborted=st.count(TrialStatus.ABORTED),
            n_pending=st.count(TrialStatus.PENDING) + st.count(TrialStatus.RUNNING),
            calibration=self.calibration, journal_removed=journal_removed,
            engine_time_s=dt, trip=self.interlock.trip_info,
            completed_names=[t.name for t in self._trials_this_run.values() if t.completed])

    def _stop_output(self) -> None:
        try:
            self.devices.stimulator.stop_now()
        except Exception:
            log.exception("stimulator.stop_now() failed")

    def _setup(self) -> None:
        stim, acq = self.devices.stimulator, self.devices.acquisition
        stim.connect()
        caps = stim.capabilities()
        cfg, p = self.config, self.config.protocol
        cfg.check_device(caps.max_current_mA, caps.model or "stimulator")
        if caps.n_channels < 2:
            raise ConfigError(cfg.source, "stimulator", caps.n_channels,
                              "a stimulator with at least 2 channels (extensor, flexor)")
        if caps.output_rate_Hz < 2 * p.carrier_Hz:
            raise ConfigError(cfg.source, "protocol.carrier_Hz", p.carrier_Hz,
                              f"below half the stimulator's output rate "
                              f"({caps.output_rate_Hz:g} Hz)")
        actual = acq.configure(p.fs_Hz)
        if not math.isclose(actual, p.fs_Hz, rel_tol=1e-6):
            raise ConfigError(cfg.source, "protocol.fs_Hz", p.fs_Hz,
                              f"a rate the acquisition supports (it would use {actual:g} Hz)")
        self.caps = caps
        if self._log is None:
            self._log = SessionLog.create(
                self.path, participant=cfg.participant, config_json=cfg.to_json(),
                seed=self.seed, backend=self.devices.backend,
                schedule_json=schedule_to_json(self.schedule), extra_attrs=self.extra_attrs)
        for utc, kind, detail in self._pending_events:
            self._log.event(kind, detail, utc=utc)
        self._pending_events.clear()
        self._event("session_start" if not self.resume_mode else "session_resume",
                    f"participant {cfg.participant}, seed {self.seed}, backend "
                    f"{self.devices.backend}, stimulator {caps.model} max "
                    f"{caps.max_current_mA:g} mA")
        if self.recovery is not None and self.recovery.action != "none":
            self._event("recovered", self.recovery.summary())
        self.interlock.start_watcher()

    def _restore_statuses(self) -> None:
        done = set()
        for meta in self._log.trials:
            idx = (meta.get("extra_attrs") or {}).get("schedule_index")
            if idx is not None and meta["status"] == "completed":
                done.add(int(idx))
        for pt in self.schedule:
            if pt.index in done:
                pt.status = TrialStatus.DONE
            pt.attempts = sum(1 for m in self._log.trials
                              if (m.get("extra_attrs") or {}).get("schedule_index") == pt.index)
        self._levels_reported = {round(pt.sE, 9) for pt in self.schedule
                                 if all(q.status is TrialStatus.DONE for q in self.schedule
                                        if round(q.sE, 9) == round(pt.sE, 9))}

    # -- trips, pauses ---------------------------------------------------------------
    def _check_interrupts(self, *, calibrating: bool = False) -> bool:
        """Between steps: handle abort, trip and pause. Returns True if the caller must
        redo its step (after re-arm / resume)."""
        self._poll()
        if self._abort_req:
            raise _EndRun("aborted by operator")
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

    # -- stimulation of one block (a calibration step or a trial) ------------------------
    def _stimulate(self, checked, *, n: int, on_samples=None, watch_commands: bool = False
                   ) -> BlockResult:
        """Run one block (:func:`nmsid.rig.stimulation.run_block`); operator commands stop it."""

        def should_stop() -> str:
            self._poll()
            if self._abort_req:
                return "session aborted by operator"
            if watch_commands:
                if self._skip_req:
                    self._skip_req = False
                    return "skipped by operator"
                if self._pause_req and \
                        self.config.protocol.pause_policy is PausePolicy.ABORT:
                    return "paused by operator (pause policy: abort)"
            return ""

        return run_block(self.devices, self.interlock, checked, n, on_samples=on_samples,
                         should_stop=should_stop)

    def _checked(self, I_ext_mA, I_flex_mA):
        c = self.config.calibration
        return check_waveform(I_ext_mA, I_flex_mA, fs_Hz=self.config.protocol.fs_Hz,
                              carrier_Hz=self.config.protocol.carrier_Hz,
                              ceiling_ext_mA=c.ceiling_ext_mA, ceiling_flex_mA=c.ceiling_flex_mA,
                              device_max_mA=self.caps.max_current_mA)

    # -- the schedule --------------------------------------------------------------------
    def _next_trial(self) -> PlannedTrial | None:
        while self._rerun_first:
            i = self._rerun_first.pop(0)
            if self.schedule[i].status is TrialStatus.PENDING:
                return self.schedule[i]
        for pt in self.schedule:
            if pt.status is TrialStatus.PENDING:
                return pt
        return None

    def _run_schedule(self) -> None:
        if self.resume_mode:  # re-run what an earlier run aborted, in schedule order
            for pt in self.schedule:
                if pt.status is TrialStatus.ABORTED:
                    pt.status, pt.reason = TrialStatus.PENDING, ""
        while True:
            self._check_interrupts()
            if self._skip_req:  # skip between trials: the next pending trial is not run
                self._skip_req = False
                nxt = self._next_trial()
                if nxt is not None:
                    nxt.status, nxt.reason = TrialStatus.ABORTED, "skipped by operator (not run)"
                    self._event("trial_skipped", f"schedule index {nxt.index} (sE "
                                                 f"{nxt.sE:g}, repeat {nxt.repeat})")
                continue
            planned = self._next_trial()
            if planned is None:
                if self._wait_for_reruns():
                    continue
                return
            self._sm.to(State.ARMED, f"next trial {planned.index}")
            self._run_trial(planned)
            if self.state is State.STIMULATING and not (
                    self.interlock.latched or self._pause_req or self._abort_req):
                self._sm.to(State.RESTING, "trial ended")
                self._rest()

    def _wait_for_reruns(self) -> bool:
        """The schedule has nothing pending. With ``WAIT_FOR_REARM`` (an operator is
        present) and aborted trials left, hold in ``paused`` (output off) until the
        operator re-runs one (returns True: the run loop continues) or ends the session
        (:meth:`abort`: the run ends normally). A trip while waiting is handled (re-arm)
        and the wait starts again. Returns False when there is nothing to wait for
        (``END_SESSION``: headless never waits)."""
        if self.trip_policy is not TripPolicy.WAIT_FOR_REARM:
            return False
        aborted = [pt for pt in self.schedule if pt.status is TrialStatus.ABORTED]
        if not aborted:
            return False
        self._stop_output()
        reason = rerun_wait_reason(len(aborted))
        self._sm.to(State.PAUSED, reason)
        self._event("waiting_for_rerun", "aborted schedule indices: " + ", ".join(
            str(pt.index) for pt in aborted))
        # pause/resume/skip mean nothing here: only re-run or end leave the wait
        self._pause_req = self._resume_req = self._skip_req = False
        try:
            self._wait_operator(lambda: self.interlock.latched or any(
                pt.status is TrialStatus.PENDING for pt in self.schedule),
                "re-run an aborted trial or end the session")
        except _EndRun:
            n = sum(pt.status is TrialStatus.ABORTED for pt in self.schedule)
            raise _EndRun(f"{RERUN_WAIT_PREFIX}; ended by operator with {n} aborted "
                          "trial(s) not re-run") from None
        if self._resume_req or self._pause_req or self._skip_req:
            self._event("command_ignored", "pause/resume/skip while waiting for a re-run")
        self._pause_req = self._resume_req = self._skip_req = False
        return True

    def _rest(self) -> None:
        if any(pt.status is TrialStatus.PENDING for pt in self.schedule):
            self._sleep_checking(self.config.protocol.rest_s)

    def _sleep_checking(self, duration_s: float) -> None:
        """Sleep on the engine clock in slices, returning early on a command or trip."""
        remaining = duration_s
        while remaining > 1e-12:
            dt = min(REST_SLICE_S, remaining)
            self.clock.sleep(dt)
            remaining -= dt
            self._poll()
            if self._abort_req or self.interlock.latched or self._pause_req or self._skip_req:
                return

    def _run_trial(self, planned: PlannedTrial) -> None:
        p = self.config.protocol
        wf = trial_waveform(p, planned.sE, self.calibration)
        try:
            checked = self._checked(wf.I_ext_mA, wf.I_flex_mA)
        except ValueError as exc:  # CurrentLimitError: never sent
            self.interlock.trip("waveform", str(exc))
            planned.status, planned.reason = TrialStatus.ABORTED, f"waveform refused: {exc}"
            return
        n = checked.n_samples
        planned.status, planned.reason = TrialStatus.RUNNING, ""
        planned.attempts += 1
        started = utc_now()
        meta = Trial(sE=planned.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz, rE=np.empty(0),
                     I_ext_mA=np.empty(0), I_flex_mA=np.empty(0), force_N=np.empty(0),
                     steady_s=p.steady_s, chirp_s=p.chirp_s, chirp_f0_Hz=p.chirp_f0_Hz,
                     chirp_f1_Hz=p.chirp_f1_Hz, carrier_Hz=p.carrier_Hz, started_utc=started,
                     extra_attrs={"schedule_index": planned.index,
                                  "attempt": planned.attempts, **input_attrs(p)})
        self._log.begin_trial(meta)
        self._event("trial_start", f"schedule index {planned.index}: sE {planned.sE:g}, "
                                   f"repeat {planned.repeat}, attempt {planned.attempts}")
        self._notify("on_trial_started", planned.index, planned)
        self._sm.to(State.STIMULATING, f"trial {planned.index}")
        rE, Ie, If = wf.rE, checked.I_ext_mA, checked.I_flex_mA

        def on_samples(lo, hi, force_seg):
            self._log.append_chunk(force_N=force_seg, rE=rE[lo:hi], I_ext_mA=Ie[lo:hi],
                                   I_flex_mA=If[lo:hi])
            self._notify("on_chunk", planned.index, lo, force_seg, rE[lo:hi], Ie[lo:hi],
                         If[lo:hi])

        blk = self._stimulate(checked, n=n, on_samples=on_samples, watch_commands=True)
        got, force, wrench, sync, reason = (blk.received, blk.force_N, blk.wrench, blk.sync,
                                            blk.abort_reason)
        trial = Trial(sE=planned.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz, rE=rE[:got].copy(),
                      I_ext_mA=np.array(Ie[:got]), I_flex_mA=np.array(If[:got]),
                      force_N=force[:got], status="aborted" if reason else "completed",
                      abort_reason=reason, steady_s=p.steady_s, chirp_s=p.chirp_s,
                      chirp_f0_Hz=p.chirp_f0_Hz, chirp_f1_Hz=p.chirp_f1_Hz,
                      carrier_Hz=p.carrier_Hz, started_utc=started,
                      wrench=None if wrench is None else wrench[:got],
                      sync=None if sync is None else sync[:got],
                      extra_attrs=dict(meta.extra_attrs))
        self._poll()  # log the trip event (if any) before the trial's own event
        name = self._log.end_trial(trial)
        planned.status = TrialStatus.ABORTED if reason else TrialStatus.DONE
        planned.reason = reason
        self._trials_this_run[planned.index] = trial
        self._event("trial_aborted" if reason else "trial_completed",
                    f"{name}: schedule index {planned.index}, sE {planned.sE:g}, repeat "
                    f"{planned.repeat}, {got} samples" + (f"; reason: {reason}" if reason
                                                          else ""))
        self._notify("on_trial_finished", planned.index, trial)
        if not reason:
            self._maybe_level_completed(planned.sE)

    def _maybe_level_completed(self, sE: float) -> None:
        key = round(sE, 9)
        entries = [pt for pt in self.schedule if round(pt.sE, 9) == key]
        if key in self._levels_reported or not all(pt.status is TrialStatus.DONE
                                                   for pt in entries):
            return
        self._levels_reported.add(key)
        trials = []
        for pt in entries:
            t = self._trials_this_run.get(pt.index)
            if t is None:
                t = self._load_completed(pt.index)
            if t is not None:
                trials.append(t)
        self._notify("on_level_completed", sE, trials)

    def _load_completed(self, index: int) -> Trial | None:
        jdir = journal_dir(self.path)
        for i, meta in enumerate(self._log.trials):
            if (meta.get("extra_attrs") or {}).get("schedule_index") == index and \
                    meta["status"] == "completed":
                p = jdir / f"trial-{i + 1:04d}.npz"
                if p.exists():
                    return load_trial_npz(p)
        return None
