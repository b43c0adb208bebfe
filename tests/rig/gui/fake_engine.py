"""A small stand-in for ``rig.engine.Engine`` that follows its contract (tests of the GUI's
own logic: threading, widgets, script runner). The end-to-end tests use the real engine.

It writes a real session file through ``protocols.session_file.SessionWriter``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from nmsid.protocols.schedule import PlannedTrial, TrialStatus
from nmsid.protocols.session_file import Calibration, Event, SessionWriter, Trial, utc_now
from nmsid.rig.observer import rerun_wait_reason
from nmsid.rig.states import State


@dataclass
class FakeSummary:
    n_completed: int
    n_aborted: int


class FakeEngine:
    chunk_n = 50           # samples per chunk
    chunk_period_s = 0.02  # wall time per chunk (fs 2000 -> 1.25x real time)

    def __init__(self, config, devices, session_path, *, resume=False, observer=None):
        self.config = config
        self.devices = devices
        self.path = session_path
        self.obs = observer
        p = config.protocol
        self.schedule = [PlannedTrial(i, sE, r) for i, (sE, r) in enumerate(
            (sE, r + 1) for sE in p.sE_levels for r in range(p.repeats))]
        self.state = State.IDLE
        self._lock = threading.Lock()
        self._estop = threading.Event()
        self._rearm = threading.Event()
        self._confirm = threading.Event()
        self._abort = threading.Event()
        self._cal = None
        self._reruns: list[int] = []
        self._notes: list[str] = []
        self.latched_reason = ""
        self.output_mA = 0.0
        self.commands = self   # the operator's commands (the real engine: engine.commands)

    # -- commands --------------------------------------------------------------------
    def estop(self, reason="operator E-stop"):
        self.output_mA = 0.0
        self.latched_reason = reason
        self._estop.set()

    def rearm(self):
        self._rearm.set()

    def pause(self):
        pass

    def resume(self):
        pass

    def abort(self):
        self._abort.set()
        self._estop.set()
        self._rearm.set()
        self._confirm.set()

    def skip_trial(self):
        pass

    def rerun(self, schedule_index):
        with self._lock:
            self._reruns.append(schedule_index)

    def confirm_calibration(self, calibration):
        self._cal = calibration
        self._confirm.set()

    def add_note(self, text):
        with self._lock:
            self._notes.append(text)

    def interlock_status(self):
        ok = not self._estop.is_set()
        return {"sensor_stream": (True, "ok"), "force_limit": (True, "ok"),
                "stimulator": (True, "ok"), "estop": (ok, "ok" if ok else self.latched_reason)}

    # -- run ---------------------------------------------------------------------------
    def _to(self, new, reason=""):
        old, self.state = self.state, new
        self._event("state", f"{old.value} -> {new.value} {reason}".strip())
        self.obs.on_state(old, new, reason)

    def _event(self, kind, detail):
        ev = Event(utc_now(), kind, detail)
        self.writer.append_events([ev])
        self.obs.on_event(ev)

    def _flush_notes(self):
        with self._lock:
            notes, self._notes = self._notes, []
        for n in notes:
            self._event("note", n)

    def _wait_for_rerun(self):
        """As the engine (WAIT_FOR_REARM): schedule done with aborted trials -> paused until
        a re-run (True) or the end of the session (False)."""
        n = sum(p.status is TrialStatus.ABORTED for p in self.schedule)
        if not n or self._abort.is_set():
            return False
        self._to(State.PAUSED, rerun_wait_reason(n))
        while not self._abort.is_set():
            with self._lock:
                if self._reruns:
                    self._to(State.ARMED, "re-run")
                    return True
            time.sleep(0.01)
        return False

    def run(self):
        self.writer = SessionWriter.create(self.path, self.config.participant,
                                           config_json=self.config.to_json(), backend="fake")
        self._to(State.CALIBRATING)
        for muscle in ("ext", "flex"):
            for k in range(8):
                self.obs.on_calibration_step(muscle, 1.0 + k, 0.8 * k)
                time.sleep(0.002)
        detected = Calibration(2.0, 7.5, 2.5, 8.0)
        self.obs.on_calibration_result(detected)
        self._confirm.wait()
        self.writer.write_calibration(self._cal)
        self._to(State.ARMED)
        p = self.config.protocol
        queue = list(range(len(self.schedule)))
        done_levels: dict[float, list] = {}
        while True:
            if not queue and not self._reruns and not self._wait_for_rerun():
                break
            self._flush_notes()
            with self._lock:
                i = self._reruns.pop(0) if self._reruns else queue.pop(0)
            planned = self.schedule[i]
            planned.status = TrialStatus.RUNNING
            self._to(State.STIMULATING)
            self.obs.on_trial_started(i, planned)
            n_total = int(p.trial_s * p.fs_Hz)
            rE = 0.5 + 0.5 * np.sin(np.arange(n_total) / p.fs_Hz * 2 * np.pi * 2)
            force = 3 * (rE - 0.5)
            aborted = ""
            n = 0
            while n < n_total:
                if self._estop.is_set():
                    aborted = self.latched_reason
                    break
                m = min(self.chunk_n, n_total - n)
                self.output_mA = 5.0
                self.obs.on_chunk(i, n, force[n:n + m], rE[n:n + m], 5 * rE[n:n + m],
                                  5 * (1 - rE[n:n + m]))
                n += m
                time.sleep(self.chunk_period_s)
            self.output_mA = 0.0
            trial = Trial(sE=planned.sE, repeat=planned.repeat, fs_Hz=p.fs_Hz,
                          rE=rE[:n], I_ext_mA=5 * rE[:n], I_flex_mA=5 * (1 - rE[:n]),
                          force_N=force[:n], status="aborted" if aborted else "completed",
                          abort_reason=aborted, steady_s=p.steady_s, chirp_s=p.chirp_s,
                          started_utc=utc_now())
            self.writer.append_trial(trial)
            planned.status = TrialStatus.ABORTED if aborted else TrialStatus.DONE
            planned.reason = aborted
            self.obs.on_trial_finished(i, trial)
            if aborted:
                self._to(State.TRIPPED, aborted)
                self._rearm.wait()
                self._rearm.clear()
                self._estop.clear()
                self._to(State.ARMED, "re-armed by operator")
                continue
            done_levels.setdefault(planned.sE, []).append(trial)
            if len(done_levels[planned.sE]) == p.repeats:
                self.obs.on_level_completed(planned.sE, done_levels[planned.sE])
            self._to(State.RESTING)
            self._to(State.ARMED)
        self._flush_notes()
        self._to(State.FINISHED)
        self.obs.on_finished(str(self.path))
        return FakeSummary(sum(s.status is TrialStatus.DONE for s in self.schedule),
                           sum(s.status is TrialStatus.ABORTED for s in self.schedule))
