"""Force-tracking sessions: the twin-based controller against a twin-free baseline.

``nmsid run --track controller.json`` runs the one engine (calibration, the journal and
the HDF5 file, the interlock and E-stop, recovery after a crash, resume) on a
:class:`TrackingSession`: a plan (:func:`tracking_plan`, checked whole before anything
stimulates) whose items are closed-loop blocks of :func:`nmsid.rig.stimulation.run_block`
with a :class:`TrackingStream`:

1. a relay-feedback trial (Astrom-Hagglund) on the participant tunes the baseline PID
   (Ziegler-Nichols), without the twin;
2. for each target (steps, a ramp, sines 0.2-2 Hz within the controller's force range, or
   ``--target FILE.csv``) the twin-based controller and the baseline each run one trial,
   interleaved and alternating which goes first, so both meet the same participant in the
   same fatigue state.

Safety, by construction: the controller commands rE, clipped to [0, 1]; the currents of
rE at the controller's sE (paper eqs. 1-4, the session's calibration) never exceed
``Imin + sE (Imax - Imin)``; they are clipped once more to the stream's ceilings, the
minimum of those limits, the session's ceilings and the device's range, and to each
channel's calibrated maximum (whatever sE); the stimulator refuses any write above the
ceilings it was opened with. The controller's sE must lie in (0, 1], its force range and
targets must be finite within the interlock's force limit and each target at most an hour
(:func:`nmsid.protocols.plan.preflight`). A controller that answers a
non-finite rE trips the interlock (output zero).

Each trial records (optional items of the session-file contract, ``docs/control.md``):
``trial_kind`` (``tracking`` / ``relay``), ``controller`` (``twin`` / ``baseline`` /
``relay``), ``target_json`` (the target's definition, rebuilt by the report),
``stream_json`` (update rate, queue, ceilings, the loop's latency per update: median,
99th percentile, max; late updates) and, for the baseline, ``pid_json``. The session's
root attributes hold ``session_kind = "tracking"``, ``tracking_controller_json`` and, when
targets were given (``--target``), ``tracking_targets_json`` (a JSON list of the targets'
definitions): what ``--resume`` rebuilds the plan from (:meth:`TrackingSession.from_stored`).
"""

from __future__ import annotations

import functools
import inspect
import json
import logging
import math
import os
import stat
import time
from dataclasses import dataclass

import numpy as np

from nmsid.analysis.control.controllers import (
    PIDController,
    PIDGains,
    RelayExperiment,
    RelayResult,
    TwinController,
    relay_analysis,
    ziegler_nichols_pid,
)
from nmsid.analysis.control.design import ControllerDesign
from nmsid.analysis.control.errors import ControlDesignError, ControllerFileError
from nmsid.analysis.control.targets import Target, load_target_csv
from nmsid.errors import SafetyError
from nmsid.protocols.plan import Plan, PlanItem, PlanRefused
from nmsid.protocols.schedule import PlannedTrial
from nmsid.protocols.waveforms import currents_mA
from nmsid.rig.engine import Engine
from nmsid.rig.trials import SessionKind, TrialNotRun, TrialRun

log = logging.getLogger(__name__)

SESSION_KIND = "tracking"
RELAY_TARGET_NAME = "relay"


class TrackingControllerError(SafetyError):
    """The controller asked for a non-finite stimulation (the interlock trips)."""


MAX_TARGET_BYTES = 1_000_000
"""A target CSV holds at most 2500 rows: a larger file is refused before it is read."""


def target_range_N(target: Target) -> tuple[float, float]:
    """Lowest and highest force of a target, from its definition (no sampling: a target
    of any stated duration costs nothing to check)."""
    p = target.params
    try:
        if target.kind == "step":
            v = [float(x) for x in p["levels_N"]]
        elif target.kind == "ramp":
            v = [float(p["low_N"]), float(p["high_N"])]
        elif target.kind == "sine":
            m, a = float(p["mean_N"]), abs(float(p["amplitude_N"]))
            v = [m - a, m + a]
        elif target.kind == "csv":
            v = [float(x) for x in p["force_N"]]
        else:
            return (math.nan, math.nan)
    except (KeyError, TypeError, ValueError):
        return (math.nan, math.nan)
    return (min(v), max(v)) if v else (math.nan, math.nan)


def tracking_plan(design: ControllerDesign, targets: list[Target] | None = None, *,
                  source: str = "", target_source: str = "") -> Plan:
    """Relay first, then per target both controllers, alternating which goes first.

    Each item carries its target (``target_json``) and envelope: the design's sE, rE in
    [0, 1] (the stream clips), the target's duration (lead-in included) and force range.
    ``source`` (``controller.json``) and ``target_source`` (a target CSV) are named by
    :func:`~nmsid.protocols.plan.preflight`'s refusals.
    """
    lo, hi = design.force_range_N
    relay_s = float(design.baseline.get("relay_s", 6.0))
    entries = [("relay", Target(RELAY_TARGET_NAME, "step",
                                {"levels_N": [0.5 * (lo + hi)], "hold_s": relay_s}, relay_s),
                source)]
    given = targets is not None
    chosen = targets if targets is not None else design.targets()
    for i, t in enumerate(chosen):
        order = ("twin", "baseline") if i % 2 == 0 else ("baseline", "twin")
        entries += [(c, t, target_source if given and target_source else source)
                    for c in order]
    items = tuple(
        PlanItem(k, "relay" if c == "relay" else "tracking", float(design.sE),
                 float(t.lead_s) + float(t.duration_s), repeat=k + 1,
                 target_range_N=target_range_N(t), label=f"{c} tracking {t.name}",
                 controller=c, source=src, target_json=t.to_json())
        for k, (c, t, src) in enumerate(entries))
    return Plan(SESSION_KIND, items, source=source)


def check_design(design: ControllerDesign, source: str) -> None:
    """The controller's numbers the plan items do not carry: its force range.

    Raises
    ------
    PlanRefused
        One line naming the file, the item, the value and what is allowed.
    """
    lo, hi = design.force_range_N
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise PlanRefused(f"{source}: force_range_N = [{lo!r}, {hi!r}] must be two finite "
                          "forces, low < high; nothing was stimulated")


@dataclass
class LoopRecord:
    """The loop's timing over one trial."""

    latency_s: list[float]
    """Per update: from the newest force sample used to the update's first output sample."""
    compute_s: list[float]
    """Per update: host time from the chunk's arrival to the update written."""
    late_updates: int = 0
    """Updates written after their slot began (they start late: the latency shows it)."""

    def summary(self) -> dict:
        lat = np.asarray(self.latency_s)
        cmp_ = np.asarray(self.compute_s)
        def q(a, p):
            return round(float(np.percentile(a, p)), 6) if a.size else None
        return {"latency_median_s": q(lat, 50), "latency_p99_s": q(lat, 99),
                "latency_max_s": q(lat, 100), "compute_median_s": q(cmp_, 50),
                "compute_max_s": q(cmp_, 100), "late_updates": int(self.late_updates),
                "n_updates": int(lat.size)}


class TrackingStream:
    """The closed-loop hook of :func:`~nmsid.rig.stimulation.run_block` for one trial.

    Parameters
    ----------
    controller
        ``start(target, target_id) -> rE of the first queue updates`` and
        ``step(j, mean force of update j) -> rE of update j + queue``.
    target_N : ndarray
        Target per update.
    sE : float
    calibration
        The session's (four currents).
    ceilings_mA : (float, float)
        The stream's ceilings (extensor, flexor).
    update_Hz, fs_Hz : float
    queue : int
    clock
        The rig's clock (latency on its time base).
    """

    def __init__(self, controller, target_N: np.ndarray, target_id: str, sE: float,
                 calibration, ceilings_mA: tuple[float, float], update_Hz: float,
                 fs_Hz: float, queue: int, clock, carrier_Hz: float | None = None):
        self.controller = controller
        self.target = np.asarray(target_N, dtype=float)
        self.target_id = target_id
        self.sE = float(sE)
        self.cal = calibration
        self.ceil_e, self.ceil_f = ceilings_mA
        self.update_Hz = float(update_Hz)
        self.fs_Hz = float(fs_Hz)
        self.queue = int(queue)
        self.clock = clock
        self.carrier_Hz = carrier_Hz
        self.M = len(self.target)
        self.spu = round(self.fs_Hz / self.update_Hz)
        self.n = self.M * self.spu
        self.rE = np.full(self.n, 0.5)
        self.I_ext_mA = np.zeros(self.n)
        self.I_flex_mA = np.zeros(self.n)
        self.next_j = 0
        self.loop = LoopRecord([], [])
        self.t0_s: float | None = None
        self.rate_Hz = self.update_Hz

    # -- safety: rE -> currents, within the ceilings by construction ---------------------
    def currents(self, rE: float) -> tuple[float, float, float]:
        """(rE clipped, I_ext_mA, I_flex_mA) for the controller's answer.

        Raises
        ------
        TrackingControllerError
            If the answer is not a finite number.
        """
        x = float(rE)
        if not math.isfinite(x):
            raise TrackingControllerError(f"the {getattr(self.controller, 'name', '')} "
                                          f"controller asked for rE = {x!r}; output stopped")
        r = min(max(x, 0.0), 1.0)
        c = self.cal
        Ie, If = currents_mA(r, self.sE, c.Iemin_mA, c.Iemax_mA, c.Ifmin_mA, c.Ifmax_mA)
        # by construction: never above the stream's ceilings nor the calibrated maxima
        return (r, min(float(Ie), self.ceil_e, float(c.Iemax_mA)),
                min(float(If), self.ceil_f, float(c.Ifmax_mA)))

    def _write(self, stim, i: int, rE: float) -> None:
        r, Ie, If = self.currents(rE)
        stim.write_stream(np.array([Ie]), np.array([If]))
        sl = slice(i * self.spu, (i + 1) * self.spu)
        self.rE[sl], self.I_ext_mA[sl], self.I_flex_mA[sl] = r, Ie, If

    # -- run_block's hook ----------------------------------------------------------------
    def open(self, stim) -> None:
        kw = {}
        if self.carrier_Hz is not None and "carrier_Hz" in inspect.signature(
                stim.open_stream).parameters:
            kw["carrier_Hz"] = self.carrier_Hz
        rate = float(stim.open_stream(self.ceil_e, self.ceil_f, self.update_Hz, **kw))
        if not math.isclose(rate, self.update_Hz, rel_tol=1e-9):
            stim.close_stream()
            raise ControlDesignError(f"the stimulator streams at {rate:g} Hz, not the "
                                     f"controller's {self.update_Hz:g} Hz; design the "
                                     f"controller with --update-hz {rate:g}")
        first = self.controller.start(self.target, self.target_id)
        for i, rE in enumerate(first):
            self._write(stim, i, rE)
        self.stim = stim
        self.t0_s = None

    def update(self, received: int, force_N: np.ndarray) -> None:
        t_arrival = time.perf_counter()
        now = self.clock.monotonic_s()
        if self.t0_s is None:   # sample index 0 is the trigger: place it on the clock
            self.t0_s = now - received / self.fs_Hz
        while (self.next_j + 1) * self.spu <= received:
            j = self.next_j
            self.next_j += 1
            i = j + self.queue
            if i >= self.M:
                continue
            y = float(np.mean(force_N[j * self.spu:(j + 1) * self.spu]))
            self._write(self.stim, i, self.controller.step(j, y))
            # when the update plays: its slot, or the first slot after it was written
            t_written = self.clock.monotonic_s()
            slot = i / self.update_Hz
            plays = max(slot, math.ceil((t_written - self.t0_s) * self.update_Hz - 1e-9)
                        / self.update_Hz)
            if plays > slot:
                self.loop.late_updates += 1
            newest = (received - 1) / self.fs_Hz
            self.loop.latency_s.append(plays - newest)
            self.loop.compute_s.append(time.perf_counter() - t_arrival)

    def close(self, stim) -> str:
        """Close the stream; the driver's report of an underrun found at close, or ""."""
        return str(stim.close_stream() or "")

    def stream_json(self) -> str:
        return json.dumps({"update_Hz": self.update_Hz, "queue": self.queue,
                           "samples_per_update": self.spu,
                           "ceiling_ext_mA": self.ceil_e, "ceiling_flex_mA": self.ceil_f,
                           **self.loop.summary()}, separators=(",", ":"))


class TrackingSession(SessionKind):
    """The kind of session of ``nmsid run --track``: its plan (:func:`tracking_plan`) and
    how one of its items runs on the engine's one trial path (a :class:`TrackingStream`).

    Parameters
    ----------
    design : ControllerDesign
        The twin-based controller (``controller.json``).
    targets : list of Target, optional
        Default: the design's (steps, ramp, sines).
    design_source, target_source : str
        The files they were read from (named by refusals).

    Raises
    ------
    PlanRefused
        The controller's force range is not two finite forces, low < high.
    """

    kind = SESSION_KIND
    reports_levels = False

    def __init__(self, design: ControllerDesign, targets: list[Target] | None = None, *,
                 design_source: str = "", target_source: str = ""):
        self.design = design
        self.targets = targets
        source = design_source or "controller.json"
        check_design(design, source)
        self._plan = tracking_plan(design, targets, source=source,
                                   target_source=target_source)
        self.pid_gains: PIDGains | None = None
        self.relay_result: RelayResult | None = None
        self._twin_ctrl: TwinController | None = None

    @classmethod
    def from_stored(cls, attrs: dict, where: str) -> TrackingSession:
        """The session kind recorded in a session's root attributes (``--resume``): the
        controller and targets as they were at the start, nothing imported.

        Raises
        ------
        ControllerFileError
            If the recorded controller or targets cannot be read.
        """
        try:
            design = ControllerDesign.from_dict(json.loads(attrs["tracking_controller_json"]),
                                                f"{where} (recorded controller)")
            text = attrs.get("tracking_targets_json")
            targets = None if text in (None, "") else [
                Target.from_json(t) for t in json.loads(text)]
        except (KeyError, TypeError, ValueError) as exc:
            raise ControllerFileError(f"{where}: the recorded tracking controller or targets "
                                      f"cannot be read ({type(exc).__name__}: {exc})"
                                      ) from None
        return cls(design, targets, design_source=f"{where} (recorded controller)",
                   target_source=f"{where} (recorded targets)")

    def plan(self, engine) -> Plan:
        return self._plan

    def root_attrs(self) -> dict:
        out = {"session_kind": SESSION_KIND,
               "tracking_controller_json": json.dumps(self.design.to_dict(),
                                                      separators=(",", ":"))}
        if self.targets is not None:   # what a resume rebuilds the plan from
            out["tracking_targets_json"] = json.dumps([t.to_json() for t in self.targets])
        return out

    def check_devices(self, devices) -> None:
        if not hasattr(devices.stimulator, "open_stream"):
            raise ControlDesignError(f"the stimulator ({devices.backend}) cannot stream "
                                     "stimulation (no host-streamed capability); tracking "
                                     "needs it")

    def schedule(self, engine) -> list[PlannedTrial]:
        return [PlannedTrial(sE=it.sE, index=it.index, repeat=it.repeat)
                for it in self._plan]

    def resume_from(self, engine, trial_attrs: list[dict]) -> None:
        """The baseline's gains from the completed relay trial (the twin controller starts
        afresh: what it learned in the earlier run is not recorded)."""
        items = self._plan.items
        if len(engine.schedule) != len(items):
            raise ControllerFileError(f"{engine.path}: {len(engine.schedule)} trials recorded "
                                      f"in its schedule, {len(items)} in the recorded "
                                      "controller's plan; it cannot be resumed")
        for a in trial_attrs:
            k = a.get("schedule_index")
            if k is not None and 0 <= int(k) < len(items) and a.get("target_json") and \
                    json.loads(a["target_json"]) != json.loads(items[int(k)].target_json):
                raise ControllerFileError(f"{engine.path}: trial at schedule index {k} "
                                          "tracked another target than the recorded plan "
                                          "holds; it cannot be resumed")
        for a in trial_attrs:
            if a.get("controller") == "relay" and a.get("status") == "completed" \
                    and a.get("pid_json"):
                try:
                    self.pid_gains = PIDGains(**json.loads(a["pid_json"]))
                except (TypeError, ValueError):
                    self.pid_gains = None

    # -- one tracking trial -------------------------------------------------------------
    def stream_ceilings(self, engine) -> tuple[float, float]:
        ce, cf = engine.trial_ceilings_mA()   # ceilings, device range, calibrated maxima
        le, lf = self.design.current_limits_mA(engine.calibration)
        return min(ce, le), min(cf, lf)

    def _controller_for(self, entry: PlanItem):
        d = self.design
        Ts = 1.0 / d.update_Hz
        if entry.controller == "twin":
            if self._twin_ctrl is None:
                self._twin_ctrl = d.make_controller()   # keeps what it learns across trials
            return self._twin_ctrl
        if entry.controller == "relay":
            b = d.baseline
            return RelayExperiment(float(b.get("relay_amplitude_rE", 0.15)),
                                   float(b.get("relay_hysteresis_N", 0.05)), Ts, d.queue)
        if self.pid_gains is None:
            raise ControlDesignError("the baseline PID has no gains: the relay trial did not "
                                     "complete or found no oscillation")
        return PIDController(self.pid_gains, Ts, d.queue)

    def prepare(self, engine, item: PlanItem, planned: PlannedTrial) -> TrialRun:
        d, p = self.design, engine.config.protocol
        try:
            ctrl = self._controller_for(item)
        except ControlDesignError as exc:
            raise TrialNotRun(str(exc)) from None
        target = Target.from_json(item.target_json)
        stream = TrackingStream(ctrl, target.samples(d.update_Hz), target.name, d.sE,
                                engine.calibration, self.stream_ceilings(engine),
                                d.update_Hz, p.fs_Hz, d.queue, engine.clock,
                                carrier_Hz=p.carrier_Hz)
        attrs = {"trial_kind": "relay" if item.controller == "relay" else "tracking",
                 "controller": item.controller, "target_json": target.to_json()}
        if item.controller == "baseline" and self.pid_gains is not None:
            attrs["pid_json"] = json.dumps(self.pid_gains.to_dict())

        def on_chunk(lo: int, hi: int) -> None:
            # the target held over each update, at the sample rate (the live plots)
            k0, k1 = lo // stream.spu, -(-hi // stream.spu)
            held = np.repeat(stream.target[k0:k1], stream.spu)
            engine._notify("on_target", planned.index, lo,
                           held[lo - k0 * stream.spu:hi - k0 * stream.spu])

        return TrialRun(n=stream.n, sE=d.sE, rE=stream.rE, I_ext_mA=stream.I_ext_mA,
                        I_flex_mA=stream.I_flex_mA, attrs=attrs, stream=stream,
                        text=f"{item.controller} tracking {target.name}",
                        on_chunk=on_chunk, state={"controller": ctrl, "item": item})

    def after_trial(self, engine, run: TrialRun, blk, completed: bool) -> dict:
        out = {"stream_json": run.stream.stream_json()}
        if run.state["item"].controller == "relay" and completed:
            out.update(self._tune_baseline(engine, blk.force_N[:blk.received], run.stream))
        return out

    def trial_written(self, engine, run: TrialRun, blk, completed: bool) -> None:
        if completed and run.state["item"].controller != "relay":
            spu, got = run.stream.spu, blk.received
            means = blk.force_N[:got - got % spu].reshape(-1, spu).mean(axis=1)
            run.state["controller"].finish(means)

    def _tune_baseline(self, engine, force_N: np.ndarray, stream: TrackingStream) -> dict:
        d = self.design
        b = d.baseline
        spu = stream.spu
        n = len(force_N) - len(force_N) % spu
        means = force_N[:n].reshape(-1, spu).mean(axis=1)
        try:
            res = relay_analysis(means, 1.0 / d.update_Hz, float(b.get("relay_amplitude_rE",
                                                                       0.15)),
                                 float(b.get("relay_hysteresis_N", 0.05)))
        except ControlDesignError as exc:
            engine._event("baseline_tuning_failed", str(exc))
            return {"relay_json": json.dumps({"error": str(exc)})}
        self.relay_result = res
        gains = self.pid_gains = ziegler_nichols_pid(res)
        engine._event("baseline_tuned", f"relay: Ku {res.ultimate_gain:.4g} rE/N, Tu "
                                        f"{res.period_s * 1000:.1f} ms -> PID Kc "
                                        f"{gains.Kc:.4g}, Ti {gains.Ti_s * 1000:.1f} ms, Td "
                                        f"{gains.Td_s * 1000:.1f} ms")
        return {"relay_json": json.dumps({"amplitude_N": res.amplitude_N,
                                          "period_s": res.period_s,
                                          "ultimate_gain": res.ultimate_gain,
                                          "n_periods": res.n_periods}),
                "pid_json": json.dumps(gains.to_dict())}


def TrackingEngine(config, devices, session_path, *, design: ControllerDesign,  # noqa: N802
                   targets: list[Target] | None = None, design_source: str = "",
                   target_source: str = "", **kw) -> Engine:
    """The engine of a new tracking session: :class:`~nmsid.rig.engine.Engine` running a
    :class:`TrackingSession` (no engine subclass: one trial path), its plan checked now.

    Raises
    ------
    PlanRefused
        A controller or target outside the contract or the rig's limits (one line, before
        any device is touched).
    """
    session = TrackingSession(design, targets, design_source=design_source,
                              target_source=target_source)
    return Engine(config, devices, session_path, session=session, **kw)


def tracking_engine(args):
    """``nmsid run --track FILE [--target FILE.csv]``: a :class:`TrackingEngine` factory
    with the design and targets read (errors in one line before any device is touched),
    or None without ``--track``.

    Raises
    ------
    ControllerFileError
        A bad controller.json or target CSV.
    ControlDesignError
        ``--target`` without ``--track``, or ``--track`` with ``--resume``.
    """
    track, target = getattr(args, "track", None), getattr(args, "target", None)
    if track is None:
        if target is not None:
            raise ControlDesignError("--target needs --track CONTROLLER.json (a target is "
                                     "tracked by a controller)")
        return None
    if getattr(args, "resume", None):
        raise ControlDesignError("--track starts a new tracking session; it cannot be "
                                 "combined with --resume")
    _check_regular(track, "--track", MAX_TARGET_BYTES)
    design = ControllerDesign.load(track)
    targets = None
    if target is not None:
        _check_regular(target, "--target", MAX_TARGET_BYTES)
        targets = [load_target_csv(target)]
    return functools.partial(TrackingEngine, design=design, targets=targets,
                             design_source=str(track),
                             target_source="" if target is None else str(target))


def _check_regular(path, option: str, max_bytes: int) -> None:
    """A file to read whole: a regular file of at most ``max_bytes`` (a FIFO or a device
    would block the read; a huge file is not a controller or a target)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return   # the reader names it
    except OSError as exc:
        raise ControllerFileError(f"{option} {path}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ControllerFileError(f"{option} {path}: not a regular file (a FIFO, a device or "
                                  "a folder); nothing was read from it")
    if st.st_size > max_bytes:
        raise ControllerFileError(f"{option} {path}: {st.st_size} bytes; at most "
                                  f"{max_bytes} (a controller or a target of 2500 rows)")
