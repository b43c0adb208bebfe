"""``nmsid probe --dry-run``: a plan of short low-current trials into a dummy load, run by
the one engine (issue 36).

The dry run is a kind of session (:class:`DryRunSession`): its plan
(:func:`nmsid.protocols.plan.dry_run_plan`) holds one ``dry_run`` item per trial, each
carrying its output envelope (the most current per channel, its duration), and the
:class:`~nmsid.rig.engine.Engine` executes it like any session: the preflight holds every
item to the ceilings before anything is connected and to the dummy load's calibration
(entered by hand: 0 .. ``--dry-run-mA`` on each channel) before the first trial; each item
runs on the engine's one trial path (the interlock, the E-stop switch and its watcher,
the journal and a session file, output at zero on every exit); a trip ends the session
(``TripPolicy.END_SESSION``, no operator at a GUI). The dry run never talks to the
stimulator itself.

The items (:data:`~nmsid.protocols.plan.DRY_RUN_ROLES`, in this order):

* ``download``: a ramp-hold-half-ramp envelope downloaded whole, as a session's trial;
* ``streamed``: one tracking-style trial, its updates written while it runs by the same
  stream hook of :func:`~nmsid.rig.stimulation.run_block` a tracking session uses
  (:class:`DryRunStream`): a slow sine in rE on the tested channel for a stimulator whose
  carrier the lock-in checks (the STG4002), a staircase of whole device steps for one that
  reports each pulse (the RehaStim2);
* ``estop``: the E-stop test: a chirp envelope (0.5 .. 10 Hz, the shape of a session's
  trial at dry-run currents) stopped by the interlock's E-stop (what the operator's button
  does) :data:`ESTOP_AT` of the way in;
  it is last, since the E-stop ends the session. A short record taken after the session
  ended shows the resistor current at zero and, for a device with a sync output, the sync
  line low.

The checks run AFTERWARDS on what each trial recorded (:class:`DryRunRecord`: the
monitor input the acquisition scanned beside force and sync, kept by
:class:`MonitorTap`; the session's sync record; what the stimulator was given or
acknowledged); :mod:`nmsid.drivers.dry_run` holds the comparisons (wiring and limits there
and in docs/hardware.md). The streamed trial is checked against what the DEVICE reports
(pulse devices: every update answered, each delivered current the command rounded down to
the device's step) or, for the STG, by the lock-in: each carrier period's amplitude on the
resistor against ``stream.commands``
(:func:`~nmsid.drivers.dry_run.check_stream_lockin`). With a Leptrino (no A/D input)
the resistor's current is not recorded: the RehaStim2 itself tests the load's
resistance before each pulse and stops with an electrode error on an open or wrong load
(ScienceMode2 1.2, 4.3), and the operator reads the amplitude on an oscilloscope across
the resistor (the line printed says what to expect).

The dry run's session file (``session_kind = "dry_run"``, participant ``DRYRUN``) is
written into a temporary folder (or ``session_dir``) and named in the output; a dry run is
not resumed (run it again).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import logging
import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.drivers.dry_run import (
    CARRIER_HZ,
    MAX_DRY_RUN_MA,
    Check,
    DryRunSettings,
    check_after_stop,
    check_loopback,
    check_pulses,
    check_stream_lockin,
    dry_run_chirp_envelope,
    dry_run_envelope,
    record_problem,
)
from nmsid.drivers.hardware import BenchClock
from nmsid.drivers.interfaces import (
    DeliveryReporting,
    HostStreamedStimulator,
    SampleTiming,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.drivers.registry import stimulator_kind
from nmsid.errors import UserError
from nmsid.protocols.calibration_settings import CalibrationConfig, ManualCurrents
from nmsid.protocols.config import Config, ProtocolConfig
from nmsid.protocols.interlock_settings import InterlockConfig
from nmsid.protocols.plan import DRY_RUN_LABELS, Plan, PlanItem, dry_run_plan
from nmsid.protocols.schedule import PlannedTrial
from nmsid.protocols.session_file import utc_now
from nmsid.rig.engine import Engine
from nmsid.rig.observer import RunSummary, TripPolicy
from nmsid.rig.trials import SessionKind, TrialNotRun, TrialRun

log = logging.getLogger(__name__)

SESSION_KIND = "dry_run"
PARTICIPANT = "DRYRUN"
SOURCE = "nmsid probe --dry-run"
DRY_RUN_INTERLOCK = InterlockConfig(stall_timeout_s=2.0)
"""A dummy load, not a participant: a late chunk on a loaded PC must not spoil the check."""
AFTER_STOP_S = 0.1
"""Length of the record taken after an E-stop."""
ESTOP_AT = 0.5
"""The E-stop test presses the E-stop at this fraction of its trial (mid-chirp)."""
STREAM_QUEUE_S = 0.5
"""Updates queued ahead in the streamed trial (a tracking session's queue is similar)."""
STREAM_LEVELS = (1.0, 0.5, 1.0, 0.25, 1.0, 0.75)
"""The pulse devices' streamed staircase, fractions of ``--dry-run-mA`` (each held 1/6 of
the trial)."""
STREAM_SINE = (0.5, 0.4, 2.0)
"""The lock-in devices' streamed target: rE = 0.5 + 0.4 sin(2 pi 2 Hz t), the tested
channel's current ``rE x --dry-run-mA`` (a slow sine within the envelope)."""
STREAM_UPDATE_HZ = 100.0
"""The update rate asked of a stimulator that takes one (the RehaStim2 answers its pulse
rate; the STG needs a divisor of its carrier: 10 carrier periods per update)."""


# -- the record of each trial -------------------------------------------------------------
class MonitorTap:
    """The acquisition, passed through, keeping the monitor input (the resistor's volts)
    and the flags of every chunk read since the last ``start``: the engine's trial path
    records force and sync; the dry run's checks need the monitor beside them."""

    def __init__(self, acquisition):
        self._acq = acquisition
        self.monitor: list[np.ndarray | None] = []
        self.flags: list[str] = []

    def reset(self) -> None:
        """Forget what was kept (a new trial)."""
        self.monitor, self.flags = [], []

    def start(self, *args, **kw):
        self.reset()
        return self._acq.start(*args, **kw)

    def read(self, timeout_s: float):
        chunk = self._acq.read(timeout_s)
        if chunk is not None:
            if chunk.n:
                self.monitor.append(chunk.monitor)
            if chunk.flags.any:
                self.flags.append(chunk.flags.detail or "flagged")
        return chunk

    def __getattr__(self, name):
        return getattr(self._acq, name)


@dataclass
class DryRunRecord:
    """What one dry-run trial recorded, for the checks run after the session."""

    role: str
    label: str
    n: int
    received: int
    abort_reason: str
    monitor: list = field(default_factory=list)
    flags: list = field(default_factory=list)
    sync: np.ndarray | None = None
    command_A: np.ndarray | None = None
    summary: dict | None = None
    status: StimulatorStatus | None = None
    resolution_mA: float = 0.0
    stream: DryRunStream | None = None


class DryRunStream:
    """:func:`~nmsid.rig.stimulation.run_block`'s stream hook (as
    :class:`~nmsid.rig.tracking.TrackingStream`): the tested channel's current written
    update by update as the trial's samples arrive, :data:`STREAM_QUEUE_S` ahead; the other
    channel at zero. ``shape``: ``sine`` (:data:`STREAM_SINE`) or ``staircase``
    (:data:`STREAM_LEVELS`). It fills ``rE`` / ``I_ext_mA`` / ``I_flex_mA`` (the trial's
    record) as it commands; ``commands`` holds each update's current in mA."""

    def __init__(self, s: DryRunSettings, fs_Hz: float, n: int, *, shape: str,
                 ceilings_mA: tuple[float, float], carrier_Hz: float | None = None):
        self.s, self.fs_Hz, self.shape = s, float(fs_Hz), shape
        self.ceilings_mA = ceilings_mA
        self.carrier_Hz = carrier_Hz
        self.rate_Hz = STREAM_UPDATE_HZ
        self.commands: list[float] = []
        self.n_updates = 0
        self.rE = np.zeros(n)
        self.I_ext_mA = np.zeros(n)
        self.I_flex_mA = np.zeros(n)
        self.stim: HostStreamedStimulator | None = None

    def envelope(self, i: int) -> float:
        """Update ``i``'s current on the tested channel, mA."""
        A, t = self.s.amplitude_mA, i / self.rate_Hz
        if self.shape == "sine":
            c, a, f = STREAM_SINE
            return float(A * (c + a * math.sin(2 * math.pi * f * t)))
        k = int(t / self.s.duration_s * len(STREAM_LEVELS))
        return float(STREAM_LEVELS[min(k, len(STREAM_LEVELS) - 1)] * A)

    def _write(self, upto: int) -> None:
        ext, stim = self.s.channel == "extensor", self.stim
        assert stim is not None    # open() set it
        first, last = len(self.commands), min(upto, self.n_updates)
        if last <= first:
            return
        a = np.minimum([self.envelope(j) for j in range(first, last)],
                       self.ceilings_mA[0 if ext else 1])
        zeros = np.zeros_like(a)
        stim.write_stream(a if ext else zeros, zeros if ext else a)   # one call, in order
        for j, aj in enumerate(a.tolist(), start=first):
            self.commands.append(aj)
            lo = round(j * self.fs_Hz / self.rate_Hz)
            hi = round((j + 1) * self.fs_Hz / self.rate_Hz)
            self.rE[lo:hi] = aj / self.s.amplitude_mA
            (self.I_ext_mA if ext else self.I_flex_mA)[lo:hi] = aj

    def open(self, stim) -> None:
        kw = {}
        if self.carrier_Hz is not None and "carrier_Hz" in inspect.signature(
                stim.open_stream).parameters:
            kw["carrier_Hz"] = self.carrier_Hz
        self.rate_Hz = float(stim.open_stream(*self.ceilings_mA, STREAM_UPDATE_HZ, **kw))
        self.n_updates = math.floor(self.s.duration_s * self.rate_Hz + 1e-9)
        self.stim = stim
        self._write(max(1, round(STREAM_QUEUE_S * self.rate_Hz)))

    def update(self, received: int, force_N) -> None:
        self._write(math.floor(received / self.fs_Hz * self.rate_Hz)
                    + round(STREAM_QUEUE_S * self.rate_Hz))

    def close(self, stim) -> str:
        """Close the stream; the driver's report of an underrun found at close, or ""."""
        return str(stim.close_stream() or "")


# -- the kind of session -------------------------------------------------------------------
def dry_run_config(s: DryRunSettings, fs_Hz: float, *,
                   ceilings_mA: tuple[float, float] = (MAX_DRY_RUN_MA, MAX_DRY_RUN_MA),
                   interlock: InterlockConfig = DRY_RUN_INTERLOCK) -> Config:
    """The dry run's session configuration: trials of ``duration_s`` at ``fs_Hz``, no rest;
    the dummy load's calibration entered by hand (0 .. ``amplitude_mA`` on each channel:
    no ramps into a resistor); ceilings at :data:`~nmsid.drivers.dry_run.MAX_DRY_RUN_MA`
    or the rig's, whichever is lower.

    Raises
    ------
    ConfigError
        A rig whose ceilings are below ``amplitude_mA`` (one line naming the setting).
    """
    ce, cf = (min(MAX_DRY_RUN_MA, float(c)) for c in ceilings_mA)
    A = s.amplitude_mA
    cal = CalibrationConfig(ceiling_ext_mA=ce, ceiling_flex_mA=cf,
                            step_mA=min(0.5, ce, cf),
                            manual=ManualCurrents(Iemin_mA=0.0, Iemax_mA=A, Ifmin_mA=0.0,
                                                  Ifmax_mA=A))
    protocol = ProtocolConfig(sE_levels=(1.0,), repeats=1, steady_s=0.0,
                              chirp_s=float(s.duration_s), chirp_f0_Hz=0.5, chirp_f1_Hz=10.0,
                              fs_Hz=float(fs_Hz), carrier_Hz=CARRIER_HZ, rest_s=0.0)
    return Config(participant=PARTICIPANT, seed=0, protocol=protocol, calibration=cal,
                  interlock=interlock, source=SOURCE)


class DryRunSession(SessionKind):
    """``nmsid probe --dry-run`` as a kind of session (see the module docstring).

    Parameters
    ----------
    s : DryRunSettings
    roles : sequence of str
        Which items to run (:data:`~nmsid.protocols.plan.DRY_RUN_ROLES`).
    support : drivers.registry.DryRunSupport
        What the stimulator kind's dry run checks.
    tap : MonitorTap
        The acquisition the engine reads (its monitor input kept per trial).
    estop_at_s : float, optional
        The E-stop test presses the E-stop this long into its trial (default
        :data:`ESTOP_AT` of it).
    plan : Plan, optional
        The plan to run instead of the one built from ``s`` (tests: an item outside the
        envelope is refused by the preflight).
    """

    kind = SESSION_KIND

    def __init__(self, s: DryRunSettings, roles, support, tap: MonitorTap, *,
                 estop_at_s: float | None = None, plan: Plan | None = None):
        self.s, self.support, self.tap = s, support, tap
        self._plan = plan if plan is not None else dry_run_plan(
            roles, s.channel, s.amplitude_mA, s.duration_s, source=SOURCE)
        by_label = {v: k for k, v in DRY_RUN_LABELS.items()}
        odd = [it for it in self._plan if it.kind != "dry_run" or it.label not in by_label]
        if odd:
            raise UserError(f"{SOURCE}: item {odd[0].index} ({odd[0].kind}, "
                            f"{odd[0].label!r}) is not a dry-run item of dry_run_plan")
        self.roles = [by_label[it.label] for it in self._plan]
        self.estop_at_s = ESTOP_AT * s.duration_s if estop_at_s is None else estop_at_s
        self.records: dict[int, DryRunRecord] = {}

    def plan(self, engine) -> Plan:
        return self._plan

    def root_attrs(self) -> dict:
        s = self.s
        return {"session_kind": SESSION_KIND, "dry_run_json": json.dumps(
            {"load_ohm": s.load_ohm, "channel": s.channel, "amplitude_mA": s.amplitude_mA,
             "duration_s": s.duration_s, "roles": self.roles}, sort_keys=True)}

    def check_devices(self, devices) -> None:
        if "streamed" in self.roles and not isinstance(devices.stimulator,
                                                       HostStreamedStimulator):
            raise UserError(f"{SOURCE}: the streamed trial needs a stimulator that streams "
                            f"({devices.backend} does not); nothing was stimulated")

    def schedule(self, engine) -> list[PlannedTrial]:
        return [PlannedTrial(index=it.index, sE=it.sE, repeat=it.repeat) for it in self._plan]

    def prepare(self, engine, item: PlanItem, planned: PlannedTrial) -> TrialRun:
        role, s = self.roles[item.index], self.s
        self.tap.reset()   # a block that fails before it starts the acquisition keeps none
        fs = engine.config.protocol.fs_Hz
        n = int(round(item.duration_s * fs))
        ext = s.channel == "extensor"
        attrs = {"trial_kind": SESSION_KIND, "dry_run_role": role}
        if role == "streamed":
            lock_in = self.support.method == "lock-in"
            ce, cf = engine.trial_ceilings_mA()   # ceilings, device range, calibration
            env_e, env_f = item.max_current_mA(engine.calibration)
            stream = DryRunStream(s, fs, n, shape="sine" if lock_in else "staircase",
                                  ceilings_mA=(min(ce, env_e), min(cf, env_f)),
                                  carrier_Hz=CARRIER_HZ if lock_in else None)
            return TrialRun(n=n, sE=item.sE, rE=stream.rE, I_ext_mA=stream.I_ext_mA,
                            I_flex_mA=stream.I_flex_mA, attrs=attrs, stream=stream,
                            text=item.label, state={"role": role, "stream": stream})
        env = (dry_run_chirp_envelope(s, fs) if role == "estop" else
               dry_run_envelope(s, fs))[:n]
        zeros = np.zeros_like(env)
        try:
            checked = engine._checked(env if ext else zeros, zeros if ext else env,
                                      calibrated=True)
        except ValueError as exc:  # CurrentLimitError: never sent
            raise TrialNotRun(f"waveform refused: {exc}", trip=str(exc)) from None
        on_chunk = None
        if role == "estop":
            press_at = round(self.estop_at_s * fs)

            def on_chunk(lo: int, hi: int) -> None:
                if hi >= press_at and not engine.interlock.latched:
                    # what the operator's E-stop does (Engine.estop): output to zero now,
                    # in this thread, and latch; the engine logs the trip and ends
                    engine.interlock.estop("dry run: E-stop test mid-chirp")
        return TrialRun(n=checked.n_samples, sE=item.sE, rE=env / s.amplitude_mA,
                        I_ext_mA=checked.I_ext_mA, I_flex_mA=checked.I_flex_mA, attrs=attrs,
                        checked=checked, text=item.label, on_chunk=on_chunk,
                        state={"role": role})

    def after_trial(self, engine, run: TrialRun, blk, completed: bool) -> dict:
        """Keep what the checks need (the device still holds what it was given)."""
        role, stim = run.state["role"], engine.devices.stimulator
        rec = DryRunRecord(role, DRY_RUN_LABELS.get(role, role), run.n, blk.received,
                           blk.abort_reason, monitor=list(self.tap.monitor),
                           flags=list(self.tap.flags),
                           sync=None if blk.sync is None else np.array(blk.sync),
                           stream=run.state.get("stream"))
        fs = engine.config.protocol.fs_Hz
        ch = engine.devices.extensor_channel if self.s.channel == "extensor" else \
            engine.devices.flexor_channel
        if role == "download" and self.support.method == "lock-in" and \
                self.support.command_A is not None:
            rec.command_A = self.support.command_A(stim, ch, run.n, fs)
        try:
            rec.summary = stim.delivery_summary() if isinstance(stim, DeliveryReporting) \
                else None
            rec.status = stim.status()
            rec.resolution_mA = float(stim.capabilities().resolution_mA)
        except Exception as exc:  # informative: the checks say what is missing
            log.warning("dry run: the stimulator's report after the trial failed: %s", exc)
        self.records[len(self.records)] = rec
        return {}


# -- running it ----------------------------------------------------------------------------
@dataclass
class DryRunResult:
    """A dry run's session and what its trials recorded."""

    kind: DryRunSession
    summary: RunSummary
    path: Path
    after_stop: tuple[np.ndarray, np.ndarray] | None = None
    """Monitor and sync volts recorded after the session ended (the E-stop test)."""

    def record(self, role: str) -> DryRunRecord | None:
        return next((r for r in self.kind.records.values() if r.role == role), None)


def run_dry_run_plan(devices, s: DryRunSettings, support, roles, *, fs_Hz: float,
                     ceilings_mA: tuple[float, float] = (MAX_DRY_RUN_MA, MAX_DRY_RUN_MA),
                     estop_at_s: float | None = None, session_dir=None,
                     interlock_cfg: InterlockConfig = DRY_RUN_INTERLOCK,
                     plan: Plan | None = None) -> DryRunResult:
    """Run the dry run's plan on the one engine; nothing is checked here.

    Raises
    ------
    PlanRefused
        An item outside the ceilings (before any device is touched) or the dummy load's
        calibration (before the first output).
    ConfigError
        The rig cannot record at ``fs_Hz`` (before anything stimulates).
    """
    tap = MonitorTap(devices.acquisition)
    rig = dataclasses.replace(devices, acquisition=tap)
    kind = DryRunSession(s, roles, support, tap, estop_at_s=estop_at_s, plan=plan)
    config = dry_run_config(s, fs_Hz, ceilings_mA=ceilings_mA, interlock=interlock_cfg)
    folder = Path(session_dir) if session_dir is not None else Path(
        tempfile.mkdtemp(prefix="nmsid-dry-run-"))
    path = folder / f"{PARTICIPANT}-{utc_now().replace(':', '').replace('-', '')}.h5"
    engine = Engine(config, rig, path, session=kind, trip_policy=TripPolicy.END_SESSION)
    summary = engine.run()
    result = DryRunResult(kind, summary, path)
    if result.record("estop") is not None:
        result.after_stop = _record_after_stop(devices, fs_Hz)
    return result


def _record_after_stop(devices, fs_Hz: float) -> tuple[np.ndarray, np.ndarray]:
    """:data:`AFTER_STOP_S` of the monitor and sync, untriggered, output stopped."""
    acq = devices.acquisition
    m = round(AFTER_STOP_S * fs_Hz)
    mon, sync = [], []
    acq.start(m, triggered=False)
    try:
        got, t_end = 0, devices.clock.monotonic_s() + AFTER_STOP_S + 2.0
        while got < m and devices.clock.monotonic_s() < t_end:
            chunk = acq.read(0.1)
            if chunk is None or not chunk.n:
                continue
            got += chunk.n
            mon.append(np.zeros(chunk.n) if chunk.monitor is None else chunk.monitor)
            sync.append(np.zeros(chunk.n) if chunk.sync is None else chunk.sync)
    finally:
        acq.stop()
    return (np.concatenate(mon) if mon else np.zeros(0),
            np.concatenate(sync) if sync else np.zeros(0))


# -- the checks, on the records --------------------------------------------------------------
def download_checks(rec: DryRunRecord, s: DryRunSettings, support, *,
                    monitor_delay_s: float = 0.0) -> list[Check]:
    """The downloaded trial's record against what the device was given."""
    problem = record_problem(rec.received, rec.n, rec.flags, rec.monitor) or rec.abort_reason
    if problem:
        return [Check("record", False, problem, "every sample, unflagged, with the monitor")]
    monitor_V = np.concatenate([m for m in rec.monitor if m is not None])[:rec.n]
    sync_V = rec.sync if rec.sync is not None else np.zeros(rec.n)
    if support.method == "lock-in":
        command = rec.command_A if rec.command_A is not None else np.zeros(rec.n)
        return check_loopback(monitor_V, sync_V, command, s, float(sync_V[0]),
                              monitor_delay_s=monitor_delay_s)
    summary = rec.summary
    if not summary:
        return [Check("pulses", False, "the stimulator reported no pulses", ">= 1")]
    shape = summary["waveshape"]
    return check_pulses(monitor_V, s, summary["channels"][s.channel]["pulse_current_mA"],
                        float(shape["pulse_width_us"]), float(shape.get("interphase_us", 0.0)),
                        pulse_index=summary.get("pulse_index"),
                        repeats=summary.get("repeats_update", True))


def estop_checks(rec: DryRunRecord, after_stop, s: DryRunSettings, support,
                 press_at: int) -> list[Check]:
    """The E-stop test: its trial ended by the E-stop near ``press_at``; the record after
    the session shows the resistor current at zero (and the sync low)."""
    by_estop = "estop" in rec.abort_reason.lower()
    checks = [Check("E-stop: trial ended", by_estop and rec.received < rec.n,
                    f"after {rec.received} of {rec.n} samples "
                    f"({rec.abort_reason or 'not stopped'})",
                    f"by the E-stop near sample {press_at}")]
    mon, sync = after_stop if after_stop is not None else (np.zeros(0), np.zeros(0))
    if not len(mon):
        checks.append(Check("E-stop: record after the stop", False, "no samples",
                            f"{round(AFTER_STOP_S * s.monitor_fs_Hz)}"))
    else:
        checks += check_after_stop(mon, sync, s, has_sync=support.hardware_sync)
    return checks


def stream_ended(rec: DryRunRecord) -> Check:
    """The streamed trial ran to its end, and the device reports its output stopped and no
    error (a trip's reason, e.g. the STG's underrun, is named)."""
    st = rec.status
    ok = (not rec.abort_reason and st is not None and st.state is not StimulatorState.ERROR
          and not st.output_active)
    detail = (f"state {st.state.value if st is not None else 'unknown'}"
              + (f", {st.error}" if st is not None and st.error else "")
              + (f"; the trial ended: {rec.abort_reason}" if rec.abort_reason else ""))
    return Check("stream: ended", ok, detail, "the whole trial, output stopped, no device "
                 "error")


def stream_checks(rec: DryRunRecord, s: DryRunSettings, support, *, fs_Hz: float,
                  out=print) -> list[Check]:
    """The streamed trial: how it ended, then the lock-in (STG) or the device's per-pulse
    reports and the pulses on the resistor (RehaStim2)."""
    stream = rec.stream
    checks = [stream_ended(rec)]
    mon = [m for m in rec.monitor if m is not None]
    if stream is None:
        return checks
    if support.method == "lock-in":
        if not mon:
            checks.append(Check("stream: amplitude", False, "the record has no monitor "
                                "channel (acquisition.monitor_channel)", "a monitor input"))
            return checks
        return checks + check_stream_lockin(np.concatenate(mon)[:rec.n], stream.commands,
                                            stream.rate_Hz, s, fs_Hz)
    summary = rec.summary
    if summary is None:
        out("  [INFO] the stimulator reports no delivered updates: only the end is checked")
        return checks
    sent, acked = summary.get("updates_sent", 0), summary.get("updates_acknowledged", 0)
    lost = sum(summary.get(k, 0) for k in ("updates_busy", "updates_transfer_error",
                                           "updates_unanswered"))
    due = math.floor(rec.received / fs_Hz * stream.rate_Hz)
    checks.append(Check("stream: updates answered", 0 < sent <= len(stream.commands) and
                        acked + lost == sent and acked >= 0.9 * sent,
                        f"{acked} of {sent} sent acknowledged ({due} due in the record), "
                        f"{lost} skipped (busy, transfer error, unanswered)",
                        ">= 90 % acknowledged, every one answered"))
    step = rec.resolution_mA
    got = summary["channels"][s.channel]["pulse_current_mA"]
    cmd = [stream.commands[k] for k in summary.get("pulse_index", [])]
    err = [c - g for c, g in zip(cmd, got, strict=False)]   # unequal: the check fails below
    checks.append(Check("stream: delivered = command rounded down",
                        len(cmd) == len(got) and all(-1e-9 <= e < step + 1e-9 for e in err),
                        f"{len(got)} pulses, command - delivered in "
                        f"[{min(err, default=0):.3g}, {max(err, default=0):.3g}] mA",
                        f"0 .. {step:g} mA (the device's step)"))
    if mon:
        shape = summary["waveshape"]
        checks += check_pulses(np.concatenate(mon)[:rec.n], s, got,
                               float(shape.get("pulse_width_us", 0.0)),
                               float(shape.get("interphase_us", 0.0)),
                               pulse_index=summary.get("pulse_index"),
                               repeats=summary.get("repeats_update", True))
    else:
        width = summary.get("waveshape", {}).get("pulse_width_us")
        out(f"  [INFO] the resistor's current is not recorded (no monitor input): "
            f"look at it on an oscilloscope across the {s.load_ohm:g} Ohm resistor, up to "
            f"+-{max(got, default=0) * 1e-3 * s.load_ohm:g} V"
            + (f" pulses of {width:g} us per phase" if width else "")
            + "; the RehaStim2 checks the load's resistance before each pulse (ScienceMode2 "
            "1.2: an open or wrong load stops it with an electrode error)")
    return checks


def report(result: DryRunResult, s: DryRunSettings, support, *, fs_Hz: float,
           monitor_delay_s: float = 0.0, out=print) -> bool:
    """Print each planned trial's checks; True if every one passed."""
    ok = True
    kind = result.kind
    for item, role in zip(kind.plan(None), kind.roles, strict=True):
        rec = result.record(role)
        out(_header(item, role, s, kind.estop_at_s))
        if rec is None:
            checks = [Check(role, False, f"not run (the session ended: "
                            f"{result.summary.ended_by})", "run")]
        else:
            out(f"  record: {rec.received} of {rec.n} samples at {fs_Hz:g} Hz"
                + (" (force, sync and monitor in one scan)" if rec.monitor and
                   rec.monitor[0] is not None else "")
                + (f"; trial ended: {rec.abort_reason}" if rec.abort_reason else ""))
            if role == "download":
                checks = download_checks(rec, s, support, monitor_delay_s=monitor_delay_s)
            elif role == "estop":
                checks = estop_checks(rec, result.after_stop, s, support,
                                      round(kind.estop_at_s * fs_Hz))
            else:
                checks = stream_checks(rec, s, support, fs_Hz=fs_Hz, out=out)
        for c in checks:
            out(c.line())
        ok = ok and all(c.passed for c in checks)
    out(f"  session: {result.path} ({result.summary.ended_by})")
    out("dry run: OK" if ok else "dry run: FAILED (see above)")
    return ok


def _header(item: PlanItem, role: str, s: DryRunSettings, estop_at_s: float) -> str:
    what = {"download": "downloaded whole", "streamed": "tracking-style updates streamed",
            "estop": f"chirp envelope, E-stop at {estop_at_s:g} s (mid-chirp)"}[role]
    return (f"{item.label}: {item.duration_s:g} s at up to {max(item.max_mA or (0, 0)):g} mA "
            f"on the {s.channel} channel into {s.load_ohm:g} Ohm, {what}; through the "
            "engine (preflight, interlock)")


def _monitor_delay_s(acq, monitor_channel: int | None) -> float:
    """How long after the scan's clock edge the A/D converts the monitor input."""
    if monitor_channel is None or not isinstance(acq, SampleTiming):
        return 0.0
    return float(acq.sample_delay_s(monitor_channel))


def run_dry_run(devices, s: DryRunSettings, support, *, out=print,
                estop_at_s: float | None = None, monitor_channel: int | None = None,
                interlock_cfg: InterlockConfig = DRY_RUN_INTERLOCK, session_dir=None,
                roles=None) -> bool:
    """One plan of dry-run trials (default: the downloaded trial, or with ``estop_at_s``
    the E-stop test) on the engine, checked and printed; True if every check passed.

    ``devices``: connected or not (the engine connects), the acquisition scanning the
    monitor input (:func:`nmsid.drivers.hardware.with_monitor`) at ``s.monitor_fs_Hz``.
    """
    roles = roles or (["estop"] if estop_at_s is not None else ["download"])
    result = run_dry_run_plan(devices, s, support, roles, fs_Hz=s.monitor_fs_Hz,
                              estop_at_s=estop_at_s, session_dir=session_dir,
                              interlock_cfg=interlock_cfg)
    return report(result, s, support, fs_Hz=s.monitor_fs_Hz, out=out,
                  monitor_delay_s=_monitor_delay_s(devices.acquisition, monitor_channel))


def dry_run_probe(devices, cfg, args, *, out=print, session_dir=None) -> bool:
    """``nmsid probe --dry-run``: settings from the flags and the hardware file; one plan
    (downloaded trial, streamed trial, E-stop test: what this rig can check) on the engine.

    ``devices`` are built from :func:`nmsid.drivers.hardware.with_monitor` ``(cfg)`` (or
    ``cfg`` itself for a chain without an A/D input). In fake mode the simulated resistor
    is "wired" as the flags say (the tested channel into the fake A/D's monitor input).
    """
    monitor = cfg.calibration is not None and cfg.calibration.monitor_channel is not None
    fs = cfg.acquisition.monitor_fs_Hz if monitor else cfg.acquisition.fs_Hz
    s = DryRunSettings(load_ohm=args.load_ohm, channel=args.dry_run_channel,
                       amplitude_mA=args.dry_run_mA,
                       monitor_fs_Hz=cfg.acquisition.monitor_fs_Hz)
    bench = devices.clock.bench if isinstance(devices.clock, BenchClock) else None
    if bench is not None:  # fake mode: the operator wired the resistor as told
        ch = devices.extensor_channel if s.channel == "extensor" else devices.flexor_channel
        bench.dummy_load = (ch - 1, s.load_ohm)
    support = stimulator_kind(cfg.stimulator).dry_run
    streams = isinstance(devices.stimulator, HostStreamedStimulator)
    if not monitor and (support.method != "pulse-amplitude" or not streams):
        out("dry run: FAILED: this acquisition has no A/D input for the resistor and this "
            "stimulator does not stream (its own delivery reports are the streamed trial's "
            "checks); use an analog chain with acquisition.monitor_channel, or an "
            "oscilloscope (docs/hardware.md, section 6)")
        return False
    roles = (["download", "estop"] if monitor else []) + (["streamed"] if streams else [])
    if not streams:
        out("dry run, streamed trial: not run (this stimulator does not stream)")
    st = cfg.stimulator
    ceilings = (float(getattr(st, "ceiling_ext_mA", MAX_DRY_RUN_MA)),
                float(getattr(st, "ceiling_flex_mA", MAX_DRY_RUN_MA)))
    name = "ceiling_ext_mA" if s.channel == "extensor" else "ceiling_flex_mA"
    ceiling = ceilings[0 if s.channel == "extensor" else 1]
    if s.amplitude_mA > ceiling:
        raise UserError(f"{cfg.source}: --dry-run-mA {s.amplitude_mA:g} is above "
                        f"stimulator.{name} = {ceiling:g} mA; use --dry-run-mA {ceiling:g} or "
                        "less; nothing was stimulated")
    out(f"dry run: {len(roles)} trial(s) into the dummy load as one plan, run by the "
        "engine after its preflight, through the interlock")
    result = run_dry_run_plan(devices, s, support, roles, fs_Hz=fs, ceilings_mA=ceilings,
                              session_dir=session_dir)
    return report(result, s, support, fs_Hz=fs, out=out, monitor_delay_s=_monitor_delay_s(
        devices.acquisition, cfg.acquisition.monitor_channel if monitor else None))
