"""Force-tracking sessions: the twin-based controller against a twin-free baseline.

``nmsid run --track controller.json`` runs a :class:`TrackingEngine`: the engine of an
identification session (calibration, the journal and the HDF5 file, the interlock and
E-stop, recovery after a crash) whose trials are closed-loop blocks of
:func:`nmsid.rig.stimulation.run_block` with a :class:`TrackingStream`:

1. a relay-feedback trial (Astrom-Hagglund) on the participant tunes the baseline PID
   (Ziegler-Nichols), without the twin;
2. for each target (steps, a ramp, sines 0.2-2 Hz within the controller's force range, or
   ``--target FILE.csv``) the twin-based controller and the baseline each run one trial,
   interleaved and alternating which goes first, so both meet the same participant in the
   same fatigue state.

Safety, by construction: the controller commands rE, clipped to [0, 1]; the currents of
rE at the controller's sE (paper eqs. 1-4, the session's calibration) never exceed
``Imin + sE (Imax - Imin)``; they are clipped once more to the stream's ceilings, the
minimum of those limits, the session's ceilings and the device's range; the stimulator
refuses any write above the ceilings it was opened with. A controller that answers a
non-finite rE trips the interlock (output zero).

Each trial records (optional items of the session-file contract, ``docs/control.md``):
``trial_kind`` (``tracking`` / ``relay``), ``controller`` (``twin`` / ``baseline`` /
``relay``), ``target_json`` (the target's definition, rebuilt by the report),
``stream_json`` (update rate, queue, ceilings, the loop's latency per update: median,
99th percentile, max; late updates) and, for the baseline, ``pid_json``. The session's
root attributes hold ``session_kind = "tracking"`` and ``tracking_controller_json``.
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
    relay_analysis,
    ziegler_nichols_pid,
)
from nmsid.analysis.control.design import ControllerDesign
from nmsid.analysis.control.errors import ControlDesignError, ControllerFileError
from nmsid.analysis.control.targets import Target, load_target_csv
from nmsid.protocols.plan import Plan, PlanItem, PlanRefused
from nmsid.protocols.schedule import PlannedTrial, TrialStatus
from nmsid.protocols.session_file import Trial, utc_now
from nmsid.protocols.waveforms import currents_mA
from nmsid.rig.engine import Engine
from nmsid.rig.states import State

from nmsid.errors import SafetyError

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

    def close(self, stim) -> None:
        stim.close_stream()

    def stream_json(self) -> str:
        return json.dumps({"update_Hz": self.update_Hz, "queue": self.queue,
                           "samples_per_update": self.spu,
                           "ceiling_ext_mA": self.ceil_e, "ceiling_flex_mA": self.ceil_f,
                           **self.loop.summary()}, separators=(",", ":"))


class TrackingEngine(Engine):
    """An :class:`~nmsid.rig.engine.Engine` whose trials are tracking trials.

    Parameters
    ----------
    config, devices, session_path
        As :class:`~nmsid.rig.engine.Engine` (new sessions only).
    design : ControllerDesign
        The twin-based controller (``controller.json``).
    targets : list of Target, optional
        Default: the design's (steps, ramp, sines).
    design_source, target_source : str
        The files they were read from (named by refusals).

    Raises
    ------
    PlanRefused
        A controller or target outside the contract or the rig's limits (one line, before
        any device is touched).
    """

    def __init__(self, config, devices, session_path, *, design: ControllerDesign,
                 targets: list[Target] | None = None, design_source: str = "",
                 target_source: str = "", **kw):
        extra = dict(kw.pop("extra_attrs", None) or {})
        extra.update({"session_kind": SESSION_KIND,
                      "tracking_controller_json": json.dumps(design.to_dict(),
                                                             separators=(",", ":"))})
        if kw.get("resume"):
            raise ControlDesignError("a tracking session cannot be resumed; start a new one "
                                     "(its completed trials stay in the file)")
        source = design_source or "controller.json"
        check_design(design, source)
        self._plan = tracking_plan(design, targets, source=source,
                                   target_source=target_source)
        super().__init__(config, devices, session_path, extra_attrs=extra, **kw)
        self.design = design
        self.schedule = [PlannedTrial(sE=it.sE, index=it.index, repeat=it.repeat)
                         for it in self._plan]
        self._preflight()   # refused here, before the caller touches a device
        self.pid_gains: PIDGains | None = None
        self.relay_result: RelayResult | None = None
        if not hasattr(devices.stimulator, "open_stream"):
            raise ControlDesignError(f"the stimulator ({devices.backend}) cannot stream "
                                     "stimulation (no host-streamed capability); tracking "
                                     "needs it")

    @property
    def plan(self) -> Plan:
        return self._plan

    # -- one tracking trial -------------------------------------------------------------
    def _stream_ceilings(self) -> tuple[float, float]:
        ce, cf = self.trial_ceilings_mA()   # ceilings, device range, calibrated maxima
        le, lf = self.design.current_limits_mA(self.calibration)
        return min(ce, le), min(cf, lf)

    def _controller_for(self, entry: PlanItem):
        d = self.design
        Ts = 1.0 / d.update_Hz
        if entry.controller == "twin":
            if not hasattr(self, "_twin_ctrl"):
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

    def _run_trial(self, planned: PlannedTrial) -> None:
        assert self._log is not None   # opened by the engine's setup, before any trial
        entry = self.plan[planned.index]
        target = Target.from_json(entry.target_json)
        p = self.config.protocol
        d = self.design
        planned.status, planned.reason = TrialStatus.RUNNING, ""
        planned.attempts += 1
        try:
            ctrl = self._controller_for(entry)
        except ControlDesignError as exc:
            planned.status, planned.reason = TrialStatus.ABORTED, str(exc)
            self._event("trial_skipped", f"schedule index {planned.index}: {exc}")
            return
        target_upd = target.samples(d.update_Hz)
        stream = TrackingStream(ctrl, target_upd, target.name, d.sE, self.calibration,
                                self._stream_ceilings(), d.update_Hz, p.fs_Hz, d.queue,
                                self.clock, carrier_Hz=p.carrier_Hz)
        n = stream.n
        started = utc_now()
        attrs = {"schedule_index": planned.index, "attempt": planned.attempts,
                 "trial_kind": "relay" if entry.controller == "relay" else "tracking",
                 "controller": entry.controller, "target_json": target.to_json()}
        if entry.controller == "baseline" and self.pid_gains is not None:
            attrs["pid_json"] = json.dumps(self.pid_gains.to_dict())
        meta = Trial(sE=d.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz, rE=np.empty(0),
                     I_ext_mA=np.empty(0), I_flex_mA=np.empty(0), force_N=np.empty(0),
                     steady_s=p.steady_s, chirp_s=p.chirp_s, chirp_f0_Hz=p.chirp_f0_Hz,
                     chirp_f1_Hz=p.chirp_f1_Hz, carrier_Hz=p.carrier_Hz, started_utc=started,
                     extra_attrs=attrs)
        self._log.begin_trial(meta)
        self._event("trial_start", f"schedule index {planned.index}: {entry.controller} "
                                   f"tracking {target.name}, attempt {planned.attempts}")
        self._notify("on_trial_started", planned.index, planned)
        self._sm.to(State.STIMULATING, f"trial {planned.index}")

        def on_samples(lo, hi, force_seg, wrench_seg=None, sync_seg=None):
            self._log.append_chunk(force_N=force_seg, rE=stream.rE[lo:hi],
                                   I_ext_mA=stream.I_ext_mA[lo:hi],
                                   I_flex_mA=stream.I_flex_mA[lo:hi], wrench=wrench_seg,
                                   sync=sync_seg)
            self._notify("on_chunk", planned.index, lo, force_seg, stream.rE[lo:hi],
                         stream.I_ext_mA[lo:hi], stream.I_flex_mA[lo:hi])
            # the target held over each update, at the sample rate (the live plots)
            k0, k1 = lo // stream.spu, -(-hi // stream.spu)
            held = np.repeat(stream.target[k0:k1], stream.spu)
            self._notify("on_target", planned.index, lo,
                         held[lo - k0 * stream.spu:hi - k0 * stream.spu])

        blk = self._stimulate(None, n=n, on_samples=on_samples, watch_commands=True,
                              stream=stream)
        got, reason = blk.received, blk.abort_reason
        attrs = {**attrs, "stream_json": stream.stream_json()}
        if entry.controller == "relay" and not reason:
            attrs.update(self._tune_baseline(blk.force_N[:got], stream))
        trial = Trial(sE=d.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz,
                      rE=stream.rE[:got].copy(), I_ext_mA=stream.I_ext_mA[:got].copy(),
                      I_flex_mA=stream.I_flex_mA[:got].copy(), force_N=blk.force_N[:got],
                      status="aborted" if reason else "completed", abort_reason=reason,
                      steady_s=p.steady_s, chirp_s=p.chirp_s, chirp_f0_Hz=p.chirp_f0_Hz,
                      chirp_f1_Hz=p.chirp_f1_Hz, carrier_Hz=p.carrier_Hz, started_utc=started,
                      wrench=None if blk.wrench is None else blk.wrench[:got],
                      sync=None if blk.sync is None else blk.sync[:got], extra_attrs=attrs)
        self._poll()
        name = self._log.end_trial(trial)
        if not reason and entry.controller != "relay":
            spu = stream.spu
            means = blk.force_N[:got - got % spu].reshape(-1, spu).mean(axis=1)
            ctrl.finish(means)
        planned.status = TrialStatus.ABORTED if reason else TrialStatus.DONE
        planned.reason = reason
        self._trials_this_run[planned.index] = trial
        self._event("trial_aborted" if reason else "trial_completed",
                    f"{name}: schedule index {planned.index}, {entry.controller} tracking "
                    f"{target.name}, {got} samples" + (f"; reason: {reason}" if reason
                                                             else ""))
        self._notify("on_trial_finished", planned.index, trial)

    def _tune_baseline(self, force_N: np.ndarray, stream: TrackingStream) -> dict:
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
            self._event("baseline_tuning_failed", str(exc))
            return {"relay_json": json.dumps({"error": str(exc)})}
        self.relay_result = res
        gains = self.pid_gains = ziegler_nichols_pid(res)
        self._event("baseline_tuned", f"relay: Ku {res.ultimate_gain:.4g} rE/N, Tu "
                                      f"{res.period_s * 1000:.1f} ms -> PID Kc "
                                      f"{gains.Kc:.4g}, Ti {gains.Ti_s * 1000:.1f} ms, Td "
                                      f"{gains.Td_s * 1000:.1f} ms")
        return {"relay_json": json.dumps({"amplitude_N": res.amplitude_N,
                                          "period_s": res.period_s,
                                          "ultimate_gain": res.ultimate_gain,
                                          "n_periods": res.n_periods}),
                "pid_json": json.dumps(gains.to_dict())}


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
