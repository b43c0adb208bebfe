"""The protocol engine: runs calibration and the trial schedule on a rig, safely, logged.

The engine executes the pure protocols (:mod:`nmsid.protocols`) through the device interfaces
(:mod:`nmsid.drivers.interfaces`). Every waveform passes :func:`nmsid.rig.safety.check_waveform`;
every output start passes the :class:`nmsid.rig.safety.Interlock` gate; every trip stops output
first, in the tripping thread. Every trial is written through
:class:`nmsid.rig.session_log.SessionLog` (journal first, then HDF5).

One class, its state declared once in :meth:`Engine.__init__`; what it runs is a plan
(:mod:`nmsid.protocols.plan`) of a kind of session (:mod:`nmsid.rig.trials`), every item
through the one trial path :meth:`Engine._run_trial`. Beside it, small pieces it calls:

* ``engine.commands`` (:class:`nmsid.rig.engine_commands.OperatorCommands`): the operator's
  commands (E-stop, re-arm, pause / resume, abort, skip, re-run, repeat, confirm the
  calibration, notes), thread-safe and callable from any thread; the engine thread acts on
  them at its next check (:meth:`Engine._poll`);
* :func:`nmsid.rig.engine_calibration.calibrate`: the calibration phase (ramps, manual, the
  operator's confirmation);
* :func:`nmsid.rig.device_recovery.check_devices_between_trials`: a USB glitch between
  trials (output zero, bounded reconnects, the operator's confirmation).

Threads: :meth:`Engine.run` blocks (the GUI calls it in a worker thread). Observer callbacks
run in the engine thread. Events name a trial as the file does (``trial t012``, the group
under ``/trials``), from its start on.
"""

from __future__ import annotations

import json
import logging
import math
import secrets
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nmsid.drivers.interfaces import (
    SINE_CARRIER,
    DeliveryReporting,
    Describable,
    RigDevices,
    StimulatorCapabilities,
    check_deliverable,
)
from nmsid.protocols.config import Config, ConfigError, PausePolicy, config_from_json
from nmsid.protocols.joints import joint_attrs
from nmsid.protocols.plan import Plan, RigLimits, preflight
from nmsid.protocols.schedule import (
    PlannedTrial,
    TrialStatus,
    make_schedule,
    schedule_from_json,
    schedule_to_json,
)
from nmsid.protocols.session_file import Calibration, Trial, utc_now
from nmsid.rig.device_recovery import (
    DeviceGlitchEnd,
    GlitchConfirm,
    check_devices_between_trials,
)
from nmsid.rig.engine_calibration import calibrate
from nmsid.rig.engine_commands import Cmd, OperatorCommands
from nmsid.rig.keep_awake import SystemAwake
from nmsid.rig.observer import (
    RERUN_WAIT_PREFIX,
    EngineObserver,
    RunSummary,
    TripPolicy,
    is_rerun_wait,
    rerun_wait_reason,
)
from nmsid.rig.safety import (
    Interlock,
    InterlockTripped,
    Trip,
    check_waveform,
    effective_ceilings,
)
from nmsid.rig.session_log import (
    SessionLog,
    check_new_session_path,
    expected_session_bytes,
    journal_dir,
    load_trial_npz,
    utc_now_ms,
)
from nmsid.rig.states import State, StateMachine
from nmsid.rig.stimulation import BlockResult, run_block
from nmsid.rig.trials import IdentificationSession, SessionKind, TrialNotRun

__all__ = ["Engine", "EngineObserver", "RunSummary", "TripPolicy", "RERUN_WAIT_PREFIX",
           "is_rerun_wait", "rerun_wait_reason"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Written:
    """A trial of this run whose level was reported: what the run's summary needs."""

    name: str
    completed: bool


#: Rest is slept in slices of this many engine-clock seconds, checking commands between.
REST_SLICE_S = 0.05


class _EndRun(Exception):
    """Internal: leave the run loop (abort, or trip under END_SESSION)."""


class Engine:
    """Runs one session: any plan, through one trial path.

    Parameters
    ----------
    config : protocols.config.Config or None
        The validated configuration (ignored with ``resume``: the session's stored one is
        used). A missing seed is drawn now and recorded.
    devices : drivers.interfaces.RigDevices
    session_path : path-like
        The HDF5 file to write (must not exist), or to continue with ``resume``.
    session : rig.trials.SessionKind, optional
        The kind of session (its plan and how its items run); default the identification
        schedule (:class:`nmsid.rig.trials.IdentificationSession`).
    resume : bool
        Continue the session in ``session_path``: recover it first if needed, skip its
        completed trials and re-run its aborted ones.
    observer : EngineObserver, optional
    trip_policy : TripPolicy
        ``WAIT_FOR_REARM`` (default, an operator is present) or ``END_SESSION``.
    extra_attrs : dict, optional
        Additional root attributes of a new session file (e.g. ``sim_seed``).
    on_device_glitch : callable(description, reconnected) -> bool, optional
        Asked after a device glitch between trials (:mod:`nmsid.rig.device_recovery`); None:
        wait for ``commands.resume()`` (the GUI).

    Attributes
    ----------
    commands : rig.engine_commands.OperatorCommands
        The operator's commands to this engine (any thread).
    """

    interlock: Interlock
    """The session's interlock: every output start passes it; any trip latches it."""
    caps: StimulatorCapabilities
    """The stimulator's capabilities, known from :meth:`run`'s set-up on."""

    def __init__(self, config: Config | None, devices: RigDevices, session_path, *,
                 resume: bool = False, observer: EngineObserver | None = None,
                 trip_policy: TripPolicy = TripPolicy.WAIT_FOR_REARM,
                 extra_attrs: dict | None = None,
                 on_device_glitch: GlitchConfirm | None = None,
                 session: SessionKind | None = None):
        self.session = session if session is not None else IdentificationSession()
        self.session.check_devices(devices)
        self.devices = devices
        self.on_device_glitch = on_device_glitch
        self.clock = devices.clock
        self.path = Path(session_path)
        self.observer = observer or EngineObserver()
        self.trip_policy = trip_policy
        self.resume_mode = resume
        self.extra_attrs = {**(extra_attrs or {}), **self.session.root_attrs()}
        self.recovery = None
        self.commands = OperatorCommands(lambda reason: self.interlock.estop(reason))
        self._log: SessionLog | None = None
        self._sm = StateMachine(self._on_transition)
        self._pending_events: list[tuple[str, str, str]] = []
        self._trials_this_run: dict[int, Trial | _Written] = {}
        """Each schedule index's trial of this run; once its level is reported, only its
        name and status (the samples are in the journal: a session keeps a few trials in
        memory, not all of them)."""
        self._levels_reported: set[float] = set()
        self._ran = False
        # operator flags (engine thread only)
        self._pause_req = self._resume_req = self._abort_req = False
        self._abort_by = "operator"  # who asked to end the session (operator, a signal)
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
            self.session.resume_from(self, [dict(m.get("extra_attrs") or {}) | {
                "status": m["status"]} for m in self._log.trials])
        else:
            if config is None:
                raise ValueError("Engine needs a configuration for a new session")
            check_new_session_path(self.path)  # names a live writer of that session
            seed = config.seed if config.seed is not None else secrets.randbelow(2 ** 31)
            self.config = config.replace(seed=seed) if config.seed is None else config
            self.seed = seed
            # the joint and what is measured (optional root attributes; docs/joints.md)
            self.extra_attrs = {**joint_attrs(self.config.joint_def), **self.extra_attrs}
            p = self.config.protocol
            self.schedule = self.session.schedule(self) or make_schedule(
                p.sE_levels, p.repeats, p.randomisation, seed, reference_sE=p.reference_sE,
                reference_every=p.reference_every)
        self.interlock = Interlock(self.config.interlock, devices.stimulator,
                                   estop_input=devices.estop, on_trip=self._on_trip,
                                   joint=self.config.joint_def)
        self._preflight()   # a bad plan is refused now, before the caller runs anything

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
        self._preflight()   # every item against the contract and the rig, before any device
        t0 = self.clock.monotonic_s()
        ended_by = "schedule complete"
        journal_removed = False
        error: BaseException | None = None
        awake = SystemAwake().__enter__()  # Windows: no sleep mid-session (this thread)
        try:
            self._setup()
            calibrate(self)
            # again with this participant's calibration, before the first trial
            self._preflight(self.calibration, device_max_mA=self.caps.max_current_mA)
            self._run_schedule()
        except (_EndRun, DeviceGlitchEnd) as exc:
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
            awake.__exit__(None, None, None)
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
        if caps.waveshape.kind == SINE_CARRIER and caps.output_rate_Hz < 2 * p.carrier_Hz:
            raise ConfigError(cfg.source, "protocol.carrier_Hz", p.carrier_Hz,
                              f"below half the stimulator's output rate "
                              f"({caps.output_rate_Hz:g} Hz)")
        for text in check_deliverable(
                caps, ceiling_ext_mA=cfg.calibration.ceiling_ext_mA,
                ceiling_flex_mA=cfg.calibration.ceiling_flex_mA, carrier_Hz=p.carrier_Hz,
                envelope_fs_Hz=p.fs_Hz, highest_envelope_Hz=p.chirp_f1_Hz):
            self._event("warning", text)
        actual = acq.configure(p.fs_Hz)
        if not math.isclose(actual, p.fs_Hz, rel_tol=1e-6):
            raise ConfigError(cfg.source, "protocol.fs_Hz", p.fs_Hz,
                              f"a rate the acquisition supports (it would use {actual:g} Hz)")
        self.caps = caps
        if self._log is None and isinstance(acq, Describable):
            # optional root attribute: what the force chain says of itself once configured
            # (a Leptrino's MEASURED record rate and its digital filter, issue 25)
            try:
                self.extra_attrs.setdefault("acquisition_json",
                                            json.dumps(acq.describe(), default=str))
            except Exception:  # informative only: never refuse a session over it
                log.exception("acquisition describe() failed")
        if self._log is None:
            self._log = SessionLog.create(
                self.path, participant=cfg.participant, config_json=cfg.to_json(),
                seed=self.seed, backend=self.devices.backend,
                schedule_json=schedule_to_json(self.schedule), extra_attrs=self.extra_attrs)
        n_left = sum(1 for t in self.schedule if t.status is not TrialStatus.DONE)
        self._log.check_space(expected_session_bytes(  # before calibration: one line
            n_left, p.n_samples, self.path.stat().st_size if self.path.exists() else 0))
        for utc, kind, detail in self._pending_events:
            self._log.event(kind, detail, utc=utc)
        self._pending_events.clear()
        self._event("session_start" if not self.resume_mode else "session_resume",
                    f"participant {cfg.participant}, seed {self.seed}, backend "
                    f"{self.devices.backend}, stimulator {caps.model} max "
                    f"{caps.max_current_mA:g} mA")
        for weakened in cfg.weakened_safety():   # confirmed, or the config was refused
            log.warning("weakened safety (confirmed): %s", weakened)
            self._event("weakened_safety", f"confirmed: {weakened}")
        if self.recovery is not None and self.recovery.action != "none":
            self._event("recovered", self.recovery.summary())
        self.interlock.start_watcher()

    # -- the plan ----------------------------------------------------------------------
    @property
    def plan(self) -> Plan:
        """What this session runs, as data (:mod:`nmsid.protocols.plan`)."""
        return self.session.plan(self)

    def _preflight(self, calibration: Calibration | None = None, *,
                   device_max_mA: float | None = None) -> None:
        """:func:`nmsid.protocols.plan.preflight` of the items still to run."""
        plan = self.plan
        left = tuple(it for it, pt in zip(plan, self.schedule, strict=True)
                     if pt.status is not TrialStatus.DONE)
        if not left:
            return
        preflight(Plan(plan.kind, left, plan.source),
                  RigLimits.of(self.config, device_max_mA), calibration)

    @property
    def _open_log(self) -> SessionLog:
        """The session's log (open from :meth:`_setup` on, or from a resume)."""
        if self._log is None:
            raise RuntimeError(f"{self.path}: the session log is not open yet")
        return self._log

    def _restore_statuses(self) -> None:
        done = set()
        for meta in self._open_log.trials:
            idx = (meta.get("extra_attrs") or {}).get("schedule_index")
            if idx is not None and meta["status"] == "completed":
                done.add(int(idx))
        for pt in self.schedule:
            if pt.index in done:
                pt.status = TrialStatus.DONE
            pt.attempts = sum(1 for m in self._open_log.trials
                              if (m.get("extra_attrs") or {}).get("schedule_index") == pt.index)
        self._levels_reported = {round(pt.sE, 9) for pt in self.schedule
                                 if all(q.status is TrialStatus.DONE for q in self.schedule
                                        if round(q.sE, 9) == round(pt.sE, 9))}

    # -- public state ------------------------------------------------------------------
    @property
    def state(self) -> State:
        return self._sm.state

    def interlock_status(self) -> dict[str, tuple[bool, str]]:
        """Rule name -> (ok, detail), plus ``latch``."""
        return self.interlock.status()

    # -- events, transitions, observers ------------------------------------------------
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

    # -- the operator's commands, as the engine thread acts on them --------------------
    def _on_trip(self, trip: Trip) -> None:
        self.commands.tripped(trip)   # any thread: handed to the engine thread

    def _poll(self) -> None:
        """Act on the queued commands (engine thread)."""
        for cmd, arg in self.commands.take():
            if cmd is Cmd.TRIPPED:
                self._event("interlock_trip", f"{arg.rule}: {arg.detail}")
            elif cmd is Cmd.PAUSE:
                self._pause_req, self._resume_req = True, False
                self._event("pause_requested", f"policy: {self.config.protocol.pause_policy.value}")
            elif cmd is Cmd.RESUME:
                self._resume_req = True
            elif cmd is Cmd.ABORT:
                if not self._abort_req:
                    self._abort_by = arg or "operator"
                self._abort_req = True
                self._event("abort_requested", arg or "operator")
            elif cmd is Cmd.SKIP:
                self._skip_req = True
            elif cmd is Cmd.REARM:
                self._rearm_req = True
            elif cmd is Cmd.CONFIRM:
                self._confirmations.append(arg)
            elif cmd is Cmd.NOTE:
                self._event("note", arg)
            elif cmd is Cmd.RERUN:
                self._queue_again(arg, TrialStatus.ABORTED, "rerun",
                                  "only aborted trials are re-run")
            elif cmd is Cmd.REPEAT:
                self._queue_again(arg[0], TrialStatus.DONE, "repeat",
                                  "only completed trials are repeated", arg[1])

    def _queue_again(self, index: int, required: TrialStatus, kind: str, rule: str,
                     reason: str = "") -> None:
        """Put a trial back to pending (it runs next) if its status is ``required``;
        otherwise log ``<kind>_refused``."""
        if not 0 <= index < len(self.schedule):
            self._event(f"{kind}_refused", f"no schedule index {index} (the session has "
                                           f"{len(self.schedule)} planned trials)")
            return
        pt = self.schedule[index]
        if pt.status is not required:
            self._event(f"{kind}_refused", f"{self._trial_label(pt)} is {pt.status.value}, "
                                           f"{rule}")
            return
        pt.status, pt.reason = TrialStatus.PENDING, ""
        self._rerun_first.append(index)
        self._levels_reported.discard(round(pt.sE, 9))
        self._event(f"{kind}_queued", f"{self._trial_label(pt)} runs next as a new trial"
                                      + (f": {reason}" if reason else ""))

    def _wait_operator(self, until, what: str) -> None:
        """Wait (real time, output off) until ``until()`` is true; abort ends the run."""
        log.info("waiting for the operator: %s", what)
        while True:
            self._poll()
            if self._abort_req:
                raise _EndRun(f"aborted by {self._abort_by}")
            if until():
                return
            self.commands.wait()

    # -- trips, pauses -------------------------------------------------------------------
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

    # -- stimulation of one block (a calibration step or a trial) ------------------------
    def _stimulate(self, checked, *, n: int, on_samples=None, watch_commands: bool = False,
                   stream=None) -> BlockResult:
        """Run one block (:func:`nmsid.rig.stimulation.run_block`); operator commands stop it.
        ``stream``: a closed-loop block (:mod:`nmsid.rig.tracking`)."""

        def should_stop() -> str:
            self._poll()
            if self._abort_req:
                return f"session aborted by {self._abort_by}"
            if watch_commands:
                if self._skip_req:
                    self._skip_req = False
                    return "skipped by operator"
                if self._pause_req and \
                        self.config.protocol.pause_policy is PausePolicy.ABORT:
                    return "paused by operator (pause policy: abort)"
            return ""

        return run_block(self.devices, self.interlock, checked, n, on_samples=on_samples,
                         should_stop=should_stop, stream=stream)

    def _checked(self, I_ext_mA, I_flex_mA, *, calibrated: bool = False):
        """The waveform checked against the ceilings; ``calibrated``: a trial, also held
        at or below each channel's calibrated maximum."""
        ce, cf = self.trial_ceilings_mA() if calibrated else (
            self.config.calibration.ceiling_ext_mA, self.config.calibration.ceiling_flex_mA)
        return check_waveform(I_ext_mA, I_flex_mA, fs_Hz=self.config.protocol.fs_Hz,
                              carrier_Hz=self.config.protocol.carrier_Hz,
                              ceiling_ext_mA=ce, ceiling_flex_mA=cf,
                              device_max_mA=self.caps.max_current_mA)

    def trial_ceilings_mA(self) -> tuple[float, float]:
        """The most a trial may command per channel: the session's ceiling, the device's
        range and this participant's calibrated maximum, whichever is lowest."""
        c, cal = self.config.calibration, self.calibration
        if cal is None:
            raise RuntimeError("no trial before the calibration is known")
        ce, cf = effective_ceilings(c.ceiling_ext_mA, c.ceiling_flex_mA,
                                    self.caps.max_current_mA)
        return min(ce, float(cal.Iemax_mA)), min(cf, float(cal.Ifmax_mA))

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
            if check_devices_between_trials(self):
                continue  # a USB glitch was recovered: look at commands and trips again
            if self._skip_req:  # skip between trials: the next pending trial is not run
                self._skip_req = False
                nxt = self._next_trial()
                if nxt is not None:
                    nxt.status, nxt.reason = TrialStatus.ABORTED, "skipped by operator (not run)"
                    self._event("trial_skipped", f"{self._trial_label(nxt)}: not run, "
                                                 "skipped by operator")
                continue
            planned = self._next_trial()
            if planned is None:
                if self._wait_for_reruns():
                    continue
                return
            self._sm.to(State.ARMED, f"next trial {self._open_log.next_trial_name}")
            self._run_trial(planned)
            if self.state is State.STIMULATING and not (
                    self.interlock.latched or self._pause_req or self._abort_req):
                self._sm.to(State.RESTING, "trial ended")
                self._rest()

    def _wait_for_reruns(self) -> bool:
        """The schedule has nothing pending. With ``WAIT_FOR_REARM`` (an operator is
        present) and aborted trials left, hold in ``paused`` (output off) until the
        operator re-runs one (returns True: the run loop continues) or ends the session
        (``commands.abort()``: the run ends normally). A trip while waiting is handled (re-arm)
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
        self._event("waiting_for_rerun", "aborted: " + "; ".join(
            self._trial_label(pt) for pt in aborted))
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
        """The one trial path of every kind of session: the kind prepares the item (a
        checked waveform or a stream hook, :mod:`nmsid.rig.trials`); the engine runs it,
        journals it, writes it and tells the observers."""
        p = self.config.protocol
        item = self.plan[planned.index]
        try:
            run = self.session.prepare(self, item, planned)
        except TrialNotRun as exc:
            planned.status, planned.reason = TrialStatus.ABORTED, str(exc)
            if exc.trip:
                self.interlock.trip("waveform", exc.trip)
            else:
                self._event("trial_skipped", f"{self._trial_label(planned)}: not run, {exc}")
            return
        planned.status, planned.reason = TrialStatus.RUNNING, ""
        planned.attempts += 1
        started = utc_now()
        attrs = {"schedule_index": planned.index, "attempt": planned.attempts, **run.attrs}

        def trial(got: int, **kw) -> Trial:
            return Trial(sE=run.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz,
                         rE=run.rE[:got].copy(), I_ext_mA=np.array(run.I_ext_mA[:got]),
                         I_flex_mA=np.array(run.I_flex_mA[:got]), steady_s=p.steady_s,
                         chirp_s=p.chirp_s, chirp_f0_Hz=p.chirp_f0_Hz,
                         chirp_f1_Hz=p.chirp_f1_Hz, carrier_Hz=p.carrier_Hz,
                         started_utc=started, **kw)

        name = self._open_log.next_trial_name   # the trial's group in the file
        label = f"trial {name} ({run.text}, attempt {planned.attempts})"
        self._open_log.begin_trial(trial(0, force_N=np.empty(0), extra_attrs=attrs))
        self._event("trial_start", label)
        self._notify("on_trial_started", planned.index, planned)
        self._sm.to(State.STIMULATING, f"trial {name}")
        rE, Ie, If = run.rE, run.I_ext_mA, run.I_flex_mA   # a stream fills them as it goes

        def on_samples(lo, hi, force_seg, wrench_seg=None, sync_seg=None):
            self._open_log.append_chunk(force_N=force_seg, rE=rE[lo:hi], I_ext_mA=Ie[lo:hi],
                                        I_flex_mA=If[lo:hi], wrench=wrench_seg,
                                        sync=sync_seg)
            self._notify("on_chunk", planned.index, lo, force_seg, rE[lo:hi], Ie[lo:hi],
                         If[lo:hi])
            if run.on_chunk is not None:
                run.on_chunk(lo, hi)

        blk = self._stimulate(run.checked, n=run.n, on_samples=on_samples,
                              watch_commands=True, stream=run.stream)
        got, reason = blk.received, blk.abort_reason
        attrs.update(self.session.after_trial(self, run, blk, not reason))
        if run.checked is not None:
            attrs.update(self._stimulation_attrs())
        t = trial(got, force_N=blk.force_N[:got], status="aborted" if reason else "completed",
                  abort_reason=reason, wrench=None if blk.wrench is None else blk.wrench[:got],
                  sync=None if blk.sync is None else blk.sync[:got], extra_attrs=attrs)
        self._poll()  # log the trip event (if any) before the trial's own event
        self._open_log.end_trial(t)   # written as ``name`` (the log names trials in order)
        self.session.trial_written(self, run, blk, not reason)
        planned.status = TrialStatus.ABORTED if reason else TrialStatus.DONE
        planned.reason = reason
        self._trials_this_run[planned.index] = t
        self._event("trial_aborted" if reason else "trial_completed",
                    f"{label}: {got} samples" + (f"; reason: {reason}" if reason else ""))
        self._notify("on_trial_finished", planned.index, t)
        if not reason and self.session.reports_levels:
            self._maybe_level_completed(planned.sE)

    def _trial_label(self, planned: PlannedTrial) -> str:
        """How events name a planned trial: as the file names it (``trial t012``, its
        latest attempt's group under ``/trials``), or, never written, by what it is."""
        what = self.plan[planned.index].label
        log_ = self._log
        names = [] if log_ is None else [
            str(m.get("name") or "") for m in log_.trials
            if (m.get("extra_attrs") or {}).get("schedule_index") == planned.index]
        if not names:
            return f"the trial {what} (not in the file)"
        return f"trial {names[-1]} ({what}, attempt {len(names)})"

    def _stimulation_attrs(self) -> dict:
        """Optional ``stimulation_json``: the stimulator's charge summary of what it was
        given to deliver (drivers that offer ``delivery_summary``, e.g. the STG4002)."""
        stim = self.devices.stimulator
        try:
            value = stim.delivery_summary() if isinstance(stim, DeliveryReporting) else None
        except Exception:  # informative only: never lose a trial over it
            log.exception("stimulator delivery_summary() failed")
            value = None
        return {} if value is None else {"stimulation_json": value}

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
            if not isinstance(t, Trial):
                t = self._load_completed(pt.index)
            if t is not None:
                trials.append(t)
        self._notify("on_level_completed", sE, trials)
        for pt in entries:  # reported: the samples are no longer needed here
            t = self._trials_this_run.get(pt.index)
            if isinstance(t, Trial):
                self._trials_this_run[pt.index] = _Written(t.name, t.completed)

    def _load_completed(self, index: int) -> Trial | None:
        jdir = journal_dir(self.path)
        for i, meta in enumerate(self._open_log.trials):
            if (meta.get("extra_attrs") or {}).get("schedule_index") == index and \
                    meta["status"] == "completed":
                p = jdir / f"trial-{i + 1:04d}.npz"
                if p.exists():
                    return load_trial_npz(p)
        return None
