"""The shared time base of the simulated rig: stimulator output, participant, faults.

One :class:`SimWorld` sits behind the three simulated devices. It maps clock time to the
absolute sample index of the rig (2000 Hz by default; sample 0 = the first stimulation
onset or acquisition start of the session), knows what the stimulator really outputs at
every sample (the loaded envelope, quantised, zero before the trigger, after the end, after
``stop_now`` or a stimulator fault), runs the participant simulation forward as the
acquisition asks for samples, and applies the fault script.

Alignment is hardware-style: the stimulator's start is the trigger, and a triggered
acquisition's sample 0 is the trigger's sample. Mapping times to samples is
``N = N_anchor + round((t - t_anchor) fs)`` with the anchor at the latest acquisition
start / trigger; on the fast clock that is exact, in real time it is the nearest sample.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from nmsid.drivers.interfaces import AcquisitionFlags
from nmsid.sim_backends.errors import DeviceStateError
from nmsid.sim_backends.faults import (
    SENSOR_KINDS,
    STIM_KINDS,
    Fault,
    FaultKind,
    FaultScript,
    FiredFault,
)
from nmsid.sim_backends.run_records import (
    AcqRun,
    OutputZero,
    RunRecord,
    SampleFault,
    SimBlock,
    StimRun,
)
from nmsid.sim_backends.simulation import simulator_for

log = logging.getLogger(__name__)

_NO_FLAGS = AcquisitionFlags()

SYNC_HIGH_V = 5.0
"""Level of the stimulator's sync output while a waveform runs (TTL)."""


class SimWorld:
    """Shared state of the simulated devices (thread-safe through ``lock``)."""

    def __init__(self, participant, clock, faults: FaultScript | None,
                 fs_Hz: float = 2000.0, chunk_s: float = 0.1, block_s: float = 15.0):
        self.lock = threading.RLock()
        self._stop_lock = threading.Lock()
        self._stop_requests: list[tuple[float, float]] = []
        self.block_n = max(1, int(round(block_s * fs_Hz)))
        self.committed = 0
        """First absolute sample not yet final (everything before was handed out)."""
        self._blk: SimBlock | None = None
        self.participant = participant
        self.clock = clock
        self.fs_Hz = float(fs_Hz)
        self.chunk_n = max(1, int(round(chunk_s * self.fs_Hz)))
        self.sim = simulator_for(participant, self.fs_Hz)
        self.script = faults if faults is not None else FaultScript()
        self.t_origin_s = clock.monotonic_s()
        self.anchor: tuple[float, int] | None = None
        self.run: StimRun | None = None
        self.records: list[RunRecord] = []
        self.n_runs = 0
        self.n_trials = 0
        self.acq: AcqRun | None = None
        self.output_zero: list[OutputZero] = []
        self.stop_calls: list[tuple[float, float]] = []
        """(clock_s, perf_counter_s) of every ``stop_now`` call."""
        self.max_sent_mA = [0.0, 0.0]
        self.max_delivered_mA = [0.0, 0.0]
        self.stim_fault: tuple[FaultKind, str] | None = None
        self.acq_fault: tuple[str, float | None] | None = None
        """A force-chain USB glitch: (text, clock time it is reachable again or None)."""
        self.estop_pressed = False
        self.estop_pressed_at_s: float | None = None
        self._timed: list[tuple[Fault, float]] = []   # (fault, clock time) for time faults
        self._sample: list[SampleFault] = []
        self.estop_due_s: list[float] = []
        """Clock times of scheduled E-stop presses (read without the lock)."""
        for f in self.script.faults:
            self._schedule_session_fault(f)

    def _schedule_session_fault(self, f: Fault) -> None:
        if f.session_s is not None:
            self._timed.append((f, self.t_origin_s + f.session_s))
            if f.kind is FaultKind.ESTOP:
                self.estop_due_s = self.estop_due_s + [self.t_origin_s + f.session_s]

    def add_fault(self, f: Fault) -> None:
        """Schedule one more fault (session time, or a trial / run not started yet)."""
        with self.lock:
            self.script.faults.append(f)
            self._schedule_session_fault(f)
            self._resolve_session_sensor_faults()

    # -- time base -----------------------------------------------------------------------
    def now(self) -> float:
        return self.clock.monotonic_s()

    def sample_at(self, t_s: float) -> int:
        """Absolute sample index at clock time ``t_s`` (never before what is simulated)."""
        if self.anchor is None:
            return self.committed
        ta, Na = self.anchor
        return max(self.committed, Na + int(round((t_s - ta) * self.fs_Hz)))

    def set_fs(self, fs_Hz: float) -> None:
        with self.lock:
            if fs_Hz == self.fs_Hz:
                return
            if self.anchor is not None:
                raise DeviceStateError(
                    f"the sampling rate can only change before the first acquisition or "
                    f"stimulation (running at {self.fs_Hz:g} Hz, asked {fs_Hz:g} Hz)")
            chunk_s = self.chunk_n / self.fs_Hz
            block_s = self.block_n / self.fs_Hz
            self.fs_Hz = float(fs_Hz)
            self.chunk_n = max(1, int(round(chunk_s * self.fs_Hz)))
            self.block_n = max(1, int(round(block_s * self.fs_Hz)))
            self.sim = simulator_for(self.participant, self.fs_Hz)

    # -- faults --------------------------------------------------------------------------
    def _log_fired(self, fault: Fault, t_s: float, N: int | None) -> None:
        k = None
        if N is not None and self.acq is not None and self.acq.N0 is not None:
            k = N - self.acq.N0
        self.script.fired.append(FiredFault(fault, t_s, N, self.run.index if self.run
                                            else None, k))
        log.info("simulated fault: %s (clock %.4f s, sample %s)", fault.describe(), t_s, N)

    def update(self) -> None:
        """Apply pending stop requests and fire every time-scheduled fault whose time has
        come (call with the lock)."""
        if self._stop_requests:
            with self._stop_lock:
                reqs, self._stop_requests = self._stop_requests, []
            for t, perf in reqs:
                self._stop_run(None, "stop_now", t, perf)
        if not self._timed:
            return
        now = self.now()
        due = [(f, t) for f, t in self._timed if t <= now and f.kind not in SENSOR_KINDS]
        for f, t in due:
            self._timed.remove((f, t))
            if f.kind is FaultKind.ESTOP:
                self.estop_pressed = True
                self.estop_pressed_at_s = t
                self._log_fired(f, t, None)
            elif f.kind in STIM_KINDS:
                N = self.sample_at(t) if self.anchor is not None else None
                self._stim_fail(f, t, N)
            elif f.kind is FaultKind.SENSOR_DISCONNECT:
                self.acq_fault = (f.detail or "force sensor USB link lost (simulated)",
                                  None if f.duration_s is None else t + f.duration_s)
                self._log_fired(f, t, None)

    def _stim_fail(self, f: Fault, t_s: float, N: int | None) -> None:
        text = f.detail or ("stimulator disconnected (simulated)"
                            if f.kind is FaultKind.STIM_DISCONNECT else
                            "stimulator error (simulated)")
        self.stim_fault = (f.kind, text)
        self._stop_run(N, f.kind.value, t_s)
        self._log_fired(f, t_s, N)

    def _resolve_run_faults(self, run: StimRun) -> None:
        """Schedule the faults given relative to this run (called at its trigger)."""
        for f in self.script.faults:
            if f.session_s is not None:
                continue
            if not ((f.run is not None and f.run == run.index)
                    or (f.trial is not None and run.trial is not None and f.trial == run.trial)):
                continue
            t = run.t_trigger_s + f.at_s
            if f.kind in SENSOR_KINDS:
                self._add_sample_fault(f, t, run.N_trigger + int(round(f.at_s * self.fs_Hz)))
            elif f.kind in STIM_KINDS and f.at_s <= 0:
                continue  # fired at load
            else:
                self._timed.append((f, t))
                if f.kind is FaultKind.ESTOP:
                    self.estop_due_s = self.estop_due_s + [t]

    def _add_sample_fault(self, f: Fault, t_s: float, N: int) -> None:
        if f.kind is FaultKind.FORCE_SPIKE:
            dur = f.duration_s if f.duration_s is not None else 0.002
        else:
            dur = f.duration_s if f.duration_s is not None else 0.0
        n_dur = max(1, int(round(dur * self.fs_Hz)))
        self._sample.append(SampleFault(f, t_s, N, N + n_dur))
        if f.kind is FaultKind.FORCE_SPIKE:
            self.invalidate()

    def _resolve_session_sensor_faults(self) -> None:
        """Give session-time sensor faults their sample, once a time base exists."""
        for f, t in list(self._timed):
            if f.kind in SENSOR_KINDS and self.anchor is not None:
                ta, Na = self.anchor
                N = Na + int(round((t - ta) * self.fs_Hz))
                if N >= self.committed:
                    self._timed.remove((f, t))
                    self._add_sample_fault(f, t, N)

    def load_faults(self, run_index: int, trial_index: int | None) -> None:
        """Stimulator faults scheduled at the very start of this run fire at load."""
        for f in self.script.faults:
            if f.kind in STIM_KINDS and f.session_s is None and f.at_s <= 0 and (
                    (f.run is not None and f.run == run_index)
                    or (f.trial is not None and trial_index is not None
                        and f.trial == trial_index)):
                if not any(ff.fault is f for ff in self.script.fired):
                    self._stim_fail(f, self.now(), None)

    # -- stimulator side -----------------------------------------------------------------
    def start_run(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray, fs_env_Hz: float,
                  is_trial: bool) -> StimRun:
        """The stimulator's start (the trigger). Call with the lock."""
        t = self.now()
        self.invalidate()
        if self.anchor is None:
            self.anchor = (t, self.committed)
        N = self.sample_at(t)
        n_out = int(math.ceil(I_ext_mA.size * self.fs_Hz / fs_env_Hz - 1e-9))
        run = StimRun(self.n_runs, self.n_trials if is_trial else None, I_ext_mA, I_flex_mA,
                      float(fs_env_Hz), t, N, n_out)
        self.n_runs += 1
        if is_trial:
            self.n_trials += 1
        self.run = run
        self.records.append(RunRecord(run.index, run.trial, t, N, n_out,
                                      max_ext_mA=float(I_ext_mA.max(initial=0.0)),
                                      max_flex_mA=float(I_flex_mA.max(initial=0.0))))
        acq = self.acq
        if acq is not None and acq.waiting and acq.triggered:
            self._bind(acq, run)
        self._resolve_run_faults(run)
        self._resolve_session_sensor_faults()
        return run

    def _bind(self, acq: AcqRun, run: StimRun) -> None:
        acq.N0, acq.t0_s, acq.run_index = run.N_trigger, run.t_trigger_s, run.index
        run.bound = True
        self.anchor = (run.t_trigger_s, run.N_trigger)
        self._resolve_session_sensor_faults()

    def _stop_run(self, N: int | None, reason: str, t_s: float,
                  perf_s: float | None = None) -> bool:
        """Output to zero from sample N (default: the sample at ``t_s``). True if the
        output was active."""
        run = self.run
        if run is None:
            return False
        if N is None:
            N = self.sample_at(t_s) if self.anchor is not None else run.N_trigger
        N = max(N, self.committed, run.N_trigger)
        was_active = self._active_at(run, t_s) and N < run.N_end
        if run.N_stop is None or N < run.N_stop:
            if N < run.N_trigger + run.n_out:
                run.N_stop = N
                run.stop_reason = run.stop_reason or reason
                if self._blk is not None and N < self._blk.N1:
                    self.invalidate()
        rec = self.records[-1]
        rec.N_end, rec.stop_reason = run.N_end, run.stop_reason
        if was_active:
            self.output_zero.append(OutputZero(
                reason, t_s, time.perf_counter() if perf_s is None else perf_s, N, run.index))
        return was_active

    def request_stop(self) -> None:
        """Output to zero now, from any thread, without waiting for a simulation in
        progress: the instant is recorded here; the samples follow at the next update."""
        t, perf = self.now(), time.perf_counter()
        with self._stop_lock:
            self._stop_requests.append((t, perf))
            self.stop_calls.append((t, perf))

    def _active_at(self, run: StimRun, t_s: float) -> bool:
        if t_s < run.t_trigger_s:
            return False
        if run.N_stop is not None and run.N_stop <= max(self.sample_at(t_s), run.N_trigger):
            return False
        return t_s < run.t_trigger_s + run.n_out / self.fs_Hz

    def output_active_at(self, t_s: float) -> bool:
        """True if the stimulator delivers current (per its run) at clock time ``t_s``."""
        if self._stop_requests:
            return False
        run = self.run
        return run is not None and self._active_at(run, t_s)

    def output(self, Na: int, Nb: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Delivered currents and the sync line for absolute samples [Na, Nb)."""
        n = Nb - Na
        I_e = np.zeros(n)
        I_f = np.zeros(n)
        sync = np.zeros(n)
        run = self.run
        if run is not None:
            lo, hi = max(Na, run.N_trigger), min(Nb, run.N_end)
            if hi > lo:
                k = np.arange(lo - run.N_trigger, hi - run.N_trigger)
                if run.fs_env_Hz == self.fs_Hz:
                    j = k
                else:
                    j = np.minimum(np.floor(k * (run.fs_env_Hz / self.fs_Hz) + 1e-9)
                                   .astype(int), run.I_ext_mA.size - 1)
                I_e[lo - Na:hi - Na] = run.I_ext_mA[j]
                I_f[lo - Na:hi - Na] = run.I_flex_mA[j]
                sync[lo - Na:hi - Na] = SYNC_HIGH_V
        return I_e, I_f, sync

    # -- acquisition side ----------------------------------------------------------------
    def start_acquisition(self, n_samples: int | None, triggered: bool) -> AcqRun:
        t = self.now()
        acq = AcqRun(triggered, n_samples, t)
        self.acq = acq
        if triggered:
            run = self.run
            if run is not None and not run.bound and self.output_active_at(t):
                self._bind(acq, run)   # the stimulator was started first: take its trigger
        else:
            if self.anchor is None:
                self.anchor = (t, self.committed)
            N = self.sample_at(t)
            acq.N0, acq.t0_s = N, t
            self.anchor = (t, N)
            self._resolve_session_sensor_faults()
        return acq

    def next_range(self, acq: AcqRun) -> tuple[int, int]:
        """Absolute [Na, Nb) of the next chunk, cut at fault boundaries."""
        N0 = acq.origin[0]
        Na = N0 + acq.next_k
        Nb = Na + self.chunk_n
        if acq.n_samples is not None:
            Nb = min(Nb, N0 + acq.n_samples)
        for sf in self._sample:
            if sf.done:
                continue
            edges = (sf.N,) if sf.fault.kind is FaultKind.SENSOR_STALL else (sf.N, sf.N_end)
            for edge in edges:
                if Na < edge < Nb:
                    Nb = edge
        return Na, Nb

    def stall_at(self, Na: int) -> SampleFault | None:
        for sf in self._sample:
            if sf.fault.kind is FaultKind.SENSOR_STALL and not sf.done and sf.N <= Na:
                return sf
        return None

    def next_timed_fault_s(self, until_s: float) -> float | None:
        """The clock time of the first time-scheduled fault still pending before
        ``until_s`` (a fast clock stops there, so a chunk never carries samples measured
        after a fault that should have cut it), else None."""
        ts = [t for f, t in self._timed if t < until_s and f.kind not in SENSOR_KINDS]
        return min(ts) if ts else None

    def due_time(self, acq: AcqRun, Nb: int) -> float:
        N0, t0_s = acq.origin
        return t0_s + (Nb - N0) / self.fs_Hz

    # -- simulation ahead, with rollback -------------------------------------------------
    def invalidate(self) -> None:
        """Drop simulated-ahead samples (the output or the faults changed): return the
        participant to the first sample not yet handed out."""
        blk = self._blk
        if blk is None:
            return
        self._blk = None
        if self.sim.cursor == self.committed:
            return
        self.sim.restore(blk.snapshot)
        n = self.committed - blk.N0
        if n > 0:   # replay what was handed out: same inputs, same (deterministic) result
            self.sim.simulate(blk.I_e[:n], blk.I_f[:n],
                              spike_N=None if blk.spike is None else blk.spike[:n])

    def _advance_to(self, N: int) -> None:
        """Run the participant forward, unmeasured, up to absolute sample N."""
        if self._blk is not None and self._blk.N0 <= N <= self._blk.N1:
            return
        self.invalidate()
        gap = N - self.sim.cursor
        if gap <= 0:
            return
        Na = self.sim.cursor
        run = self.run
        if run is not None and run.N_end > Na and run.N_trigger < N:
            I_e, I_f, _ = self.output(Na, N)
            self._count_delivered(I_e, I_f)
            self.sim.simulate(I_e, I_f)
        else:
            self.sim.advance_quiet(gap)
        self.committed = max(self.committed, N)

    def _ensure(self, acq: AcqRun, Na: int, Nb: int) -> SimBlock:
        """A valid simulated block covering [Na, Nb)."""
        blk = self._blk
        if blk is not None and blk.N0 <= Na and Nb <= blk.N1:
            return blk
        if blk is not None:
            # everything before Na is final (handed out, or lost by an overrun)
            self.committed = max(self.committed, min(Na, blk.N1))
            self.invalidate()
        self._advance_to(Na)
        # a participant that cannot be rolled back (a plug-in without snapshot/restore)
        # is simulated only as far as is handed out now: never ahead
        n = Nb - Na if getattr(self.sim, "forward_only", False) else self.block_n
        if acq.n_samples is not None:
            n = min(n, acq.origin[0] + acq.n_samples - Na)
        n = max(n, Nb - Na)
        N1 = Na + n
        I_e, I_f, sync = self.output(Na, N1)
        spike = None
        for sf in self._sample:
            if sf.fault.kind is FaultKind.FORCE_SPIKE and sf.N < N1 and sf.N_end > Na:
                if spike is None:
                    spike = np.zeros(n)
                spike[max(sf.N, Na) - Na:min(sf.N_end, N1) - Na] += sf.fault.amplitude_N
        snap = self.sim.snapshot()
        out = self.sim.simulate(I_e, I_f, spike_N=spike)
        rng = self.participant.sensor.range_N
        over = np.abs(out.wrench[:, :3]).max(axis=1) >= rng if \
            np.abs(out.force_N).max(initial=0.0) >= rng * 0.5 else None
        for arr in (sync, out.force_N, out.wrench):
            arr.setflags(write=False)      # chunks are views of these: read-only
        self._blk = SimBlock(Na, N1, snap, I_e, I_f, spike, sync, out.force_N, out.wrench, over,
                           float(I_e.max(initial=0.0)), float(I_f.max(initial=0.0)))
        return self._blk

    def _count_delivered(self, I_e: np.ndarray, I_f: np.ndarray,
                         peaks: tuple[float, float] | None = None) -> None:
        if peaks is not None and peaks[0] <= self.max_delivered_mA[0] \
                and peaks[1] <= self.max_delivered_mA[1]:
            return   # nothing in this block can raise the record
        if I_e.size:
            self.max_delivered_mA[0] = max(self.max_delivered_mA[0], float(I_e.max()))
            self.max_delivered_mA[1] = max(self.max_delivered_mA[1], float(I_f.max()))

    def acquire(self, acq: AcqRun, Na: int, Nb: int):
        """Hand out [Na, Nb): (force_N, wrench, sync, flags, start_index)."""
        self.update()
        flags = {"overrun": False, "over_range": False, "sensor_fault": False}
        details = []
        if acq.lost_detail:
            flags["overrun"] = True
            details.append(acq.lost_detail)
            acq.lost_detail = ""
        pending = [sf for sf in self._sample if not sf.done]
        for sf in pending:
            if (not sf.done and sf.fault.kind is FaultKind.OVERRUN and Na <= sf.N < Nb
                    and sf.fault.lost_s > 0):
                lost = int(round(sf.fault.lost_s * self.fs_Hz))
                Na = sf.N + lost
                Nb = Na + self.chunk_n
                if acq.n_samples is not None:
                    Nb = min(Nb, acq.origin[0] + acq.n_samples)
                Na = min(Na, Nb)
                flags["overrun"] = True
                details.append(f"simulated overrun: {lost} samples lost")
                sf.done = True
                if not any(ff.fault is sf.fault for ff in self.script.fired):
                    self._log_fired(sf.fault, sf.t_s, sf.N)
        blk = self._ensure(acq, Na, Nb)
        for sf in pending:
            if sf.done or sf.N >= max(Nb, Na + 1) or sf.N_end <= Na:
                continue
            kind = sf.fault.kind
            if kind is FaultKind.OVER_RANGE:
                flags["over_range"] = True
            elif kind is FaultKind.SENSOR_FAULT:
                flags["sensor_fault"] = True
            elif kind is FaultKind.OVERRUN:
                flags["overrun"] = True
            elif kind is not FaultKind.FORCE_SPIKE:
                continue
            if kind is not FaultKind.FORCE_SPIKE:
                details.append(f"simulated {kind.value}")
            if not any(ff.fault is sf.fault for ff in self.script.fired):
                self._log_fired(sf.fault, sf.t_s, sf.N)
            if sf.N_end <= Nb:
                sf.done = True
        a, b = Na - blk.N0, Nb - blk.N0
        if blk.over is not None and blk.over[a:b].any():
            flags["over_range"] = True
            details.append(f"force beyond the sensor's range "
                           f"{self.participant.sensor.range_N:g} N")
        self._count_delivered(blk.I_e[a:b], blk.I_f[a:b], (blk.peak_e, blk.peak_f))
        self.committed = max(self.committed, Nb)
        N0 = acq.origin[0]
        acq.next_k = Nb - N0
        fl = AcquisitionFlags(detail="; ".join(details), **flags) if details else _NO_FLAGS
        return blk.force_N[a:b], blk.wrench[a:b], blk.sync[a:b], fl, Na - N0

    def start_stall(self, acq: AcqRun, sf: SampleFault) -> None:
        if not any(ff.fault is sf.fault for ff in self.script.fired):
            self._log_fired(sf.fault, sf.t_s, sf.N)
        acq.stalled = True
        acq.stall_end_s = (None if sf.fault.duration_s is None
                           else sf.t_s + sf.fault.duration_s)

    def stop_acquisition(self) -> None:
        acq = self.acq
        if acq is None:
            return
        for sf in self._sample:
            if sf.fault.kind is FaultKind.SENSOR_STALL and not sf.done and acq.stalled:
                sf.done = True   # a stall lasts until the acquisition is restarted
        self.acq = None
