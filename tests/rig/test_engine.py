"""The engine on a tiny fake rig: the whole flow, operator commands, trips, resume."""

import threading

import numpy as np
import pytest

from nmsid.protocols.config import ConfigError
from nmsid.protocols.schedule import TrialStatus
from nmsid.protocols.session_file import Calibration, read_session, validate_session
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy, is_rerun_wait
from nmsid.rig.session_log import journal_dir
from nmsid.rig.states import State


class Recorder(EngineObserver):
    def __init__(self):
        self.calls = []
        self.hooks = {}
        self.chunks = 0

    def _hook(self, name, *a):
        fn = self.hooks.get(name)
        if fn:
            fn(*a)

    def on_state(self, old, new, reason):
        self.calls.append(("state", old, new))
        self._hook("state", old, new, reason)

    def on_event(self, event):
        self.calls.append(("event", event.kind))

    def on_calibration_step(self, muscle, current_mA, force_N):
        self.calls.append(("cal_step", muscle, current_mA, force_N))

    def on_calibration_result(self, calibration):
        self.calls.append(("cal", calibration))
        self._hook("cal", calibration)

    def on_trial_started(self, index, planned):
        self.calls.append(("started", index))
        self._hook("started", index, planned)

    def on_chunk(self, index, start_index, force_N, rE, I_ext_mA, I_flex_mA):
        assert len(force_N) == len(rE) == len(I_ext_mA) == len(I_flex_mA)
        self.chunks += 1
        self._hook("chunk", index, start_index)

    def on_trial_finished(self, index, trial):
        self.calls.append(("finished", index, trial.status, trial.abort_reason))
        self._hook("finished", index, trial)

    def on_level_completed(self, sE, trials):
        self.calls.append(("level", sE, len(trials)))

    def on_finished(self, path):
        self.calls.append(("end", path))

    def kinds(self, k):
        return [c for c in self.calls if c[0] == k]


def test_whole_session_on_the_fake_rig(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    path = tmp_path / "s.h5"
    eng = Engine(small_config(), rig, path, observer=obs)
    assert len(eng.schedule) == 4 and eng.state is State.IDLE
    s = eng.run()
    assert s.ended_by == "schedule complete" and s.complete and s.journal_removed
    assert eng.state is State.FINISHED and not journal_dir(path).exists()
    assert validate_session(path) == []
    sess = read_session(path)
    # fake muscles: ext k=1 above 2 mA, flex k=0.8 above 1.5 mA (force = 0.5 N at 2.5 mA)
    assert (sess.calibration.Iemin_mA, sess.calibration.Iemax_mA) == (2.5, 7.0)
    assert (sess.calibration.Ifmin_mA, sess.calibration.Ifmax_mA) == (2.5, 8.0)
    assert "ext_force_N" in sess.calibration.ramps
    assert [t.extra_attrs["schedule_index"] for t in sess.trials] == [0, 1, 2, 3]
    assert [(t.sE, t.repeat) for t in sess.trials] == [(p.sE, p.repeat) for p in eng.schedule]
    for t in sess.trials:
        assert t.completed and t.n_samples == 3000
        # the stored currents are what eqs (1)-(4) give for the stored rE
        cal = sess.calibration
        assert np.allclose(t.I_ext_mA, cal.Iemin_mA + t.rE * t.sE * (cal.Iemax_mA - cal.Iemin_mA))
    # the recorded force is what the fake computed from the currents it was sent
    t0 = sess.trials[0]
    expect = 1.0 * np.maximum(0, t0.I_ext_mA - 2.0) - 0.8 * np.maximum(0, t0.I_flex_mA - 1.5)
    assert np.allclose(t0.force_N, expect)
    assert len(obs.kinds("level")) == 2 and all(c[2] == 2 for c in obs.kinds("level"))
    assert obs.chunks == 4 * 15 and obs.kinds("end")
    kinds = [e.kind for e in sess.events]
    assert kinds.count("trial_completed") == 4 and "session_end" in kinds
    assert rig.stimulator.output_active is False
    assert sess.seed == 7 and '"participant": "T01"' in sess.config_json


def test_refuses_existing_file_and_device_mismatch(tmp_path, fake_rig, small_config):
    path = tmp_path / "s.h5"
    path.write_bytes(b"x")
    with pytest.raises(FileExistsError):
        Engine(small_config(), fake_rig(), path)
    rig = fake_rig()
    rig.stimulator.caps = rig.stimulator.caps.__class__(2, 10.0, 0.01, 1e5)
    eng = Engine(small_config(), rig, tmp_path / "b.h5")
    with pytest.raises(ConfigError, match="ceiling_ext_mA"):
        eng.run()
    assert rig.stimulator.started == 0 and not (tmp_path / "b.h5").exists()


def test_estop_mid_trial_waits_for_rearm_then_rerun(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", observer=obs)
    fired = []

    def chunk(index, start):
        if index == 1 and start >= 1000 and not fired:
            fired.append(1)
            threading.Thread(target=eng.commands.estop, args=("button",)).start()

    def state(old, new, reason):
        if new is State.TRIPPED:
            assert rig.stimulator.output_active is False
            eng.commands.rearm()
            eng.commands.rerun(1)

    obs.hooks = {"chunk": chunk, "state": state}
    s = eng.run()
    sess = read_session(tmp_path / "s.h5")
    aborted = [t for t in sess.trials if not t.completed]
    assert len(aborted) == 1 and aborted[0].abort_reason == "estop: button"
    assert 1000 <= aborted[0].n_samples < 3000  # samples before the stop kept
    assert aborted[0].extra_attrs["schedule_index"] == 1
    # re-run right after re-arm: index 1 ran twice, everything completed in the end
    idx = [t.extra_attrs["schedule_index"] for t in sess.trials]
    assert idx == [0, 1, 1, 2, 3] and s.complete
    kinds = [e.kind for e in sess.events]
    assert "interlock_trip" in kinds and "rearmed" in kinds and "rerun_queued" in kinds
    assert validate_session(tmp_path / "s.h5") == []


@pytest.mark.parametrize("policy, n_first", [("finish", 3000), ("abort", None)])
def test_pause_policies(tmp_path, fake_rig, small_config, policy, n_first):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(protocol={"pause_policy": policy}), rig, tmp_path / "s.h5",
                 observer=obs)

    def chunk(index, start):
        if index == 0 and start == 1000:
            eng.commands.pause()

    def state(old, new, reason):
        if new is State.PAUSED:
            assert rig.stimulator.output_active is False
            if is_rerun_wait(new, reason):  # "abort": trial 0 is left aborted at the end
                eng.commands.abort()
            else:
                eng.commands.resume()
    obs.hooks = {"chunk": chunk, "state": state}
    eng.run()
    sess = read_session(tmp_path / "s.h5")
    first = sess.trials[0]
    if n_first:
        assert first.completed and first.n_samples == n_first and len(sess.trials) == 4
    else:
        assert not first.completed and "paused" in first.abort_reason
        assert first.n_samples < 3000
        assert eng.schedule[0].status is TrialStatus.ABORTED
    assert ("state", State.STIMULATING, State.PAUSED) in obs.calls


def test_abort_and_skip(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", observer=obs)

    def chunk(index, start):
        if index == 0 and start == 600:
            eng.commands.skip_trial()
        if index == 2 and start == 400:
            eng.commands.abort()
    obs.hooks = {"chunk": chunk}
    s = eng.run()
    assert s.ended_by == "aborted by operator" and s.n_completed == 1 and s.n_pending == 1
    sess = read_session(tmp_path / "s.h5")
    assert [t.abort_reason for t in sess.trials] == ["skipped by operator", "",
                                                     "session aborted by operator"]
    assert rig.stimulator.output_active is False and validate_session(tmp_path / "s.h5") == []


@pytest.mark.parametrize("fault, words", [
    ("stall", "sensor_stream: no force samples"),
    ("over_range", "acquisition: acquisition reported over-range"),
    ("spike", "force_limit: force 1000.00 N"),
    ("stim_error", "stimulator: stimulator error: injected error"),
    ("empty_fault", "acquisition: acquisition reported sensor fault: A/D error 7"),
])
def test_faults_abort_the_trial_with_reason_and_keep_completed(tmp_path, fake_rig,
                                                              small_config, fault, words):
    rig = fake_rig()
    # second started output = the calibration's first ramp... count starts: find trial 1's
    eng = Engine(small_config(), rig, tmp_path / "s.h5", trip_policy=TripPolicy.END_SESSION)
    obs = Recorder()
    eng.observer = obs

    def started(index, planned):
        if index == 1:
            rig.acquisition.faults[fault] = (rig.stimulator.started + 1, 1500)
    obs.hooks = {"started": started}
    s = eng.run()
    assert s.ended_by.startswith("interlock: " + words.split(":")[0])
    sess = read_session(tmp_path / "s.h5")
    assert [t.status for t in sess.trials] == ["completed", "aborted"]
    assert sess.trials[1].abort_reason.startswith(words)
    assert 1000 <= sess.trials[1].n_samples <= 1600
    assert any(e.kind == "interlock_trip" and e.detail.startswith(words) for e in sess.events)
    assert rig.stimulator.output_active is False
    assert validate_session(tmp_path / "s.h5") == []


def test_resume_skips_completed_and_reruns_aborted(tmp_path, fake_rig, small_config):
    path = tmp_path / "s.h5"
    rig = fake_rig()
    eng = Engine(small_config(), rig, path, trip_policy=TripPolicy.END_SESSION)
    obs = Recorder()
    obs.hooks = {"chunk": lambda i, s: eng.commands.estop("stop") if (i == 1 and s == 1000)
                 else None}
    eng.observer = obs
    s = eng.run()
    assert s.n_completed == 1 and s.n_aborted == 1 and s.n_pending == 2
    before = read_session(path)
    rig2 = fake_rig()
    eng2 = Engine(None, rig2, path, resume=True)
    assert [p.status for p in eng2.schedule][:1] == [TrialStatus.DONE]
    s2 = eng2.run()
    assert s2.complete
    after = read_session(path)
    idx = [t.extra_attrs["schedule_index"] for t in after.trials]
    assert idx == [0, 1, 1, 2, 3]
    assert np.array_equal(after.trials[0].force_N, before.trials[0].force_N)
    # calibration reused: no ramp on the second rig, 3 trials started
    assert rig2.stimulator.started == 3
    assert validate_session(path) == []


def test_operator_confirms_or_edits_calibration(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(calibration={"confirm": True}), rig, tmp_path / "s.h5",
                 observer=obs)
    edited = Calibration(2.0, 6.5, 2.0, 7.5)

    def cal(c):
        eng.commands.confirm_calibration(Calibration(2.0, 99.0, 2.0, 7.5))  # above ceiling: refused
        eng.commands.confirm_calibration(edited)
    obs.hooks = {"cal": cal}
    eng.run()
    sess = read_session(tmp_path / "s.h5")
    assert sess.calibration.Iemax_mA == 6.5 and "ext_force_N" in sess.calibration.ramps
    assert [e.kind for e in sess.events].count("calibration_refused") == 1


def test_manual_calibration_skips_ramps(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    cfg = small_config(calibration={"manual": {"Iemin_mA": 2, "Iemax_mA": 7, "Ifmin_mA": 2,
                                               "Ifmax_mA": 8}})
    Engine(cfg, rig, tmp_path / "s.h5").run()
    assert rig.stimulator.started == 4
    assert read_session(tmp_path / "s.h5").calibration.Ifmax_mA == 8


def test_failed_calibration_stops_before_any_trial(tmp_path, fake_rig, small_config):
    rig = fake_rig(k_e=0.01)  # a muscle that never reaches Fmax under the ceiling
    from nmsid.protocols.errors import CalibrationError
    eng = Engine(small_config(), rig, tmp_path / "s.h5")
    with pytest.raises(CalibrationError, match="extensor"):
        eng.run()
    assert rig.stimulator.output_active is False
    assert all(w.n_samples <= 400 for w in rig.stimulator.received)  # only ramp steps


def test_notes_status_and_commands_from_other_threads(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", observer=obs)
    st = eng.interlock_status()
    assert {"force_limit", "sensor_stream", "acquisition", "stimulator", "estop",
            "latch"} <= set(st) and all(ok for ok, _ in st.values())

    def started(index, planned):
        if index == 0:
            t = threading.Thread(target=eng.commands.add_note, args=("participant said: tingling",))
            t.start()
            t.join()
            eng.commands.rerun(99)   # refused: no such trial
            eng.commands.rerun(3)    # refused: pending, not aborted
    obs.hooks = {"started": started}
    eng.run()
    ev = read_session(tmp_path / "s.h5").events
    assert any(e.kind == "note" and e.detail == "participant said: tingling" for e in ev)
    assert [e.kind for e in ev].count("rerun_refused") == 2
    # the state events tell the whole story, in order, all legal
    states = [e.detail.split(":")[0] for e in ev if e.kind == "state"]
    assert states[0] == "idle -> calibrating" and states[-1].endswith("-> finished")


def test_estop_while_paused_then_abort_while_tripped(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", observer=obs)

    def chunk(index, start):
        if index == 1 and start == 200:
            eng.commands.pause()

    def state(old, new, reason):
        if new is State.PAUSED:
            threading.Thread(target=eng.commands.estop, args=("while paused",)).start()
        if new is State.TRIPPED:
            eng.commands.abort()
    obs.hooks = {"chunk": chunk, "state": state}
    s = eng.run()
    assert s.ended_by == "aborted by operator" and eng.state is State.FINISHED
    assert s.trip is not None and s.trip.detail == "while paused"
    moves = [(c[1], c[2]) for c in obs.kinds("state")]
    assert (State.STIMULATING, State.PAUSED) in moves
    assert (State.PAUSED, State.TRIPPED) in moves and moves[-1][1] is State.FINISHED
    sess = read_session(tmp_path / "s.h5")
    assert [t.status for t in sess.trials] == ["completed", "completed"]  # pause = finish
    assert rig.stimulator.output_active is False and validate_session(tmp_path / "s.h5") == []


def test_estop_before_run_blocks_all_output(tmp_path, fake_rig, small_config):
    rig = fake_rig()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", trip_policy=TripPolicy.END_SESSION)
    eng.commands.estop("before start")
    s = eng.run()
    assert s.ended_by == "interlock: estop: before start"
    assert rig.stimulator.started == 0 and s.n_completed == 0


def _stop_last_trial(eng, how):
    """A chunk hook that E-stops (another thread) or skips the last trial (index 3)."""
    fired = []

    def chunk(index, start):
        if index == 3 and start >= 1000 and not fired:
            fired.append(1)
            if how == "estop":
                threading.Thread(target=eng.commands.estop, args=("last",)).start()
            else:
                eng.commands.skip_trial()
    return chunk


@pytest.mark.parametrize("how", ["estop", "skip"])
def test_last_trial_aborted_waits_for_rerun_then_completes(tmp_path, fake_rig, small_config,
                                                           how):
    """WAIT_FOR_REARM: the last trial is aborted, (re-armed), nothing is pending: the
    engine does not finish but waits in ``paused`` until the operator re-runs it."""
    rig = fake_rig()
    obs = Recorder()
    path = tmp_path / "s.h5"
    eng = Engine(small_config(), rig, path, observer=obs)
    waits = []

    def state(old, new, reason):
        if new is State.TRIPPED:
            eng.commands.rearm()  # no re-run queued before the re-arm
        if new is State.PAUSED:
            assert rig.stimulator.output_active is False
            assert is_rerun_wait(new, reason), reason
            assert all(p.status is not TrialStatus.PENDING for p in eng.schedule)
            waits.append(reason)
            eng.commands.resume()  # means nothing here: ignored, the engine keeps waiting
            threading.Timer(0.1, eng.commands.rerun, args=(3,)).start()
    obs.hooks = {"chunk": _stop_last_trial(eng, how), "state": state}
    s = eng.run()
    assert waits == ["schedule done; 1 aborted trial(s) can be re-run; re-run or end the "
                     "session"]
    assert s.complete and s.ended_by == "schedule complete" and s.journal_removed
    moves = [(c[1], c[2]) for c in obs.kinds("state")]
    assert (State.PAUSED, State.ARMED) in moves and moves[-1] == (State.RESTING,
                                                                  State.FINISHED)
    sess = read_session(path)
    assert [t.extra_attrs["schedule_index"] for t in sess.trials] == [0, 1, 2, 3, 3]
    assert [t.completed for t in sess.trials] == [True, True, True, False, True]
    kinds = [e.kind for e in sess.events]
    assert kinds.count("waiting_for_rerun") == 1 and "rerun_queued" in kinds
    assert "command_ignored" in kinds
    assert validate_session(path) == [] and not journal_dir(path).exists()


def test_ending_the_rerun_wait_finishes_cleanly(tmp_path, fake_rig, small_config):
    """While waiting for a re-run: an E-stop trips (re-arm, the wait starts again), then
    the operator ends the session: a normal end, file valid, journal removed."""
    rig = fake_rig()
    obs = Recorder()
    path = tmp_path / "s.h5"
    eng = Engine(small_config(), rig, path, observer=obs)
    waits = []

    def state(old, new, reason):
        if new is State.TRIPPED:
            assert rig.stimulator.output_active is False
            eng.commands.rearm()
        if is_rerun_wait(new, reason):
            waits.append(old)
            if len(waits) == 1:
                threading.Thread(target=eng.commands.estop, args=("while waiting",)).start()
            else:
                eng.commands.abort()
    obs.hooks = {"chunk": _stop_last_trial(eng, "estop"), "state": state}
    s = eng.run()
    assert waits == [State.ARMED, State.ARMED]  # tripped -> armed -> paused, twice
    assert s.ended_by == "schedule done; ended by operator with 1 aborted trial(s) not re-run"
    assert not s.complete and (s.n_completed, s.n_aborted, s.n_pending) == (3, 1, 0)
    assert s.journal_removed and eng.state is State.FINISHED
    moves = [(c[1], c[2]) for c in obs.kinds("state")]
    assert (State.PAUSED, State.TRIPPED) in moves and moves[-1] == (State.PAUSED,
                                                                    State.FINISHED)
    assert validate_session(path) == [] and not journal_dir(path).exists()
    sess = read_session(path)
    assert [t.completed for t in sess.trials] == [True, True, True, False]
    kinds = [e.kind for e in sess.events]
    assert kinds.count("waiting_for_rerun") == 2 and kinds[-1] == "session_end"
    assert rig.stimulator.output_active is False


@pytest.mark.parametrize("how", ["estop", "skip"])
def test_end_session_policy_never_waits_for_a_rerun(tmp_path, fake_rig, small_config, how):
    rig = fake_rig()
    obs = Recorder()
    path = tmp_path / "s.h5"
    eng = Engine(small_config(), rig, path, observer=obs, trip_policy=TripPolicy.END_SESSION)
    obs.hooks = {"chunk": _stop_last_trial(eng, how)}
    s = eng.run()
    assert s.ended_by == ("interlock: estop: last" if how == "estop" else "schedule complete")
    assert (s.n_completed, s.n_aborted, s.n_pending) == (3, 1, 0)
    assert State.PAUSED not in [c[2] for c in obs.kinds("state")]
    assert "waiting_for_rerun" not in [e.kind for e in read_session(path).events]
    assert validate_session(path) == []


def test_repeat_a_completed_trial_writes_a_new_attempt(tmp_path, fake_rig, small_config):
    """The operator repeats a completed trial (the quality control excluded it): it runs
    next, the recorded one stays, and a pending trial cannot be 'repeated'."""
    rig = fake_rig()
    obs = Recorder()
    eng = Engine(small_config(), rig, tmp_path / "s.h5", observer=obs)
    asked = []

    def finished(index, trial):
        if index == 0 and not asked:
            asked.append(1)
            eng.commands.repeat_trial(3, "not done yet")        # refused: still pending
            eng.commands.repeat_trial(0, "QC excluded it: contraction at 1.0-1.4 s")

    obs.hooks = {"finished": finished}
    s = eng.run()
    sess = read_session(tmp_path / "s.h5")
    idx = [t.extra_attrs["schedule_index"] for t in sess.trials]
    assert idx == [0, 0, 1, 2, 3] and s.complete
    assert all(t.completed for t in sess.trials)
    kinds = [(e.kind, e.detail) for e in sess.events]
    assert any(k == "repeat_refused" and "pending" in d for k, d in kinds)
    assert any(k == "repeat_queued" and "QC excluded it" in d for k, d in kinds)
    assert validate_session(tmp_path / "s.h5") == []
