"""A USB glitch between trials (issue 16): reconnect, pause for the operator, resume in the
same process with nothing lost; each device in turn, on the simulated rig's fault injection.
"""

from __future__ import annotations

import pytest

from nmsid.protocols.config import config_from_dict
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.device_recovery import RECONNECT_ATTEMPTS
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy
from nmsid.rig.states import State
from nmsid.sim_backends import Fault, FaultKind, make_sim_rig

TRIAL_S = 1.5  # steady 0.5 s + chirp 1.0 s


def _cfg():
    return config_from_dict({
        "participant": "G01", "seed": 3,
        "protocol": {"sE_levels": [0.5, 0.7, 0.9], "repeats": 1, "steady_s": 0.5,
                     "chirp_s": 1.0, "rest_s": 2.0},
        "calibration": {"manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                                   "Ifmax_mA": 8.0}}})


def _between_trials(kind, **kw):
    # 1 s into the rest after trial 0: no trial is running
    return Fault(kind, trial=0, at_s=TRIAL_S + 1.0, **kw)


def _kinds(sess, kind):
    return [e.detail for e in sess.events if e.kind == kind]


@pytest.mark.parametrize("kind, device", [(FaultKind.SENSOR_DISCONNECT, "acquisition"),
                                          (FaultKind.STIM_DISCONNECT, "stimulator")])
def test_glitch_between_trials_is_survived_in_one_process(tmp_path, kind, device):
    rig = make_sim_rig(seed=1, faults=[_between_trials(kind)])
    asked = []
    eng = Engine(_cfg(), rig, tmp_path / "g.h5", trip_policy=TripPolicy.END_SESSION,
                 on_device_glitch=lambda what, ok: asked.append((what, ok)) or True)
    s = eng.run()
    assert s.ended_by == "schedule complete" and s.n_completed == 3 and s.n_aborted == 0
    assert [f.fault.kind for f in rig.faults.fired] == [kind]
    assert len(asked) == 1 and asked[0][1] is True and asked[0][0].startswith(device)
    sess = read_session(tmp_path / "g.h5")
    assert validate_session(tmp_path / "g.h5") == []
    assert [t.status for t in sess.trials] == ["completed"] * 3
    assert all(t.n_samples == 3000 for t in sess.trials)
    glitch = _kinds(sess, "device_glitch")
    assert len(glitch) == 1 and glitch[0].startswith(device)
    assert _kinds(sess, "reconnect_attempt") == [f"{device}: attempt 1 of "
                                                 f"{RECONNECT_ATTEMPTS} succeeded"]
    assert len(_kinds(sess, "waiting_for_operator")) == 1
    states = _kinds(sess, "state")
    i = next(k for k, d in enumerate(states) if d.startswith("resting -> paused"))
    assert states[i + 1].startswith("paused -> armed: resumed after reconnect")
    # output was zero through the glitch: no stimulator run overlaps the paused period
    assert rig.max_sent_mA[0] <= 9.5 + 1e-9


def test_operator_confirms_through_resume_in_the_gui_path(tmp_path):
    rig = make_sim_rig(seed=1, faults=[_between_trials(FaultKind.SENSOR_DISCONNECT)])

    class Operator(EngineObserver):
        engine = None
        paused = []

        def on_state(self, old, new, reason):
            if new is State.PAUSED and "glitch" in reason:
                self.paused.append(reason)
                self.engine.commands.resume()

    op = Operator()
    eng = Engine(_cfg(), rig, tmp_path / "g.h5", observer=op)
    op.engine = eng
    s = eng.run()
    assert s.n_completed == 3 and s.n_aborted == 0
    assert len(op.paused) == 1 and "reconnected" in op.paused[0]


def test_no_confirmation_ends_cleanly_and_resume_continues(tmp_path):
    path = tmp_path / "g.h5"
    rig = make_sim_rig(seed=1, faults=[_between_trials(FaultKind.SENSOR_DISCONNECT)])
    s = Engine(_cfg(), rig, path, trip_policy=TripPolicy.END_SESSION,
               on_device_glitch=lambda what, ok: False).run()
    assert s.n_completed == 1 and s.n_pending == 2
    assert "session ended for --resume" in s.ended_by
    assert validate_session(path) == []
    s2 = Engine(None, make_sim_rig(seed=1), path, resume=True,
                trip_policy=TripPolicy.END_SESSION).run()
    assert s2.ended_by == "schedule complete"
    sess = read_session(path)
    assert [t.status for t in sess.trials] == ["completed"] * 3


def test_reconnect_retries_are_bounded_and_logged(tmp_path):
    # the sensor is away for 2.8 s (1.8 s after the rest ends, when it is found): 3
    # attempts 0.5 s apart fail, the operator asks to try again, a later one succeeds
    rig = make_sim_rig(seed=1, faults=[_between_trials(FaultKind.SENSOR_DISCONNECT,
                                                        duration_s=2.8)])
    answers = []
    s = Engine(_cfg(), rig, tmp_path / "g.h5", trip_policy=TripPolicy.END_SESSION,
               on_device_glitch=lambda what, ok: answers.append(ok) or True).run()
    assert s.n_completed == 3
    assert answers == [False, True]
    attempts = _kinds(read_session(tmp_path / "g.h5"), "reconnect_attempt")
    assert sum("failed" in a for a in attempts) >= RECONNECT_ATTEMPTS
    assert sum("succeeded" in a for a in attempts) == 1
    assert all(a.startswith("acquisition: attempt ") for a in attempts)


def test_glitch_during_a_trial_aborts_that_trial_as_before(tmp_path):
    rig = make_sim_rig(seed=1, faults=[Fault(FaultKind.SENSOR_DISCONNECT, trial=1,
                                             at_s=0.7)])
    s = Engine(_cfg(), rig, tmp_path / "g.h5", trip_policy=TripPolicy.END_SESSION,
               on_device_glitch=lambda what, ok: True).run()
    assert s.n_aborted == 1 and s.n_completed == 1
    sess = read_session(tmp_path / "g.h5")
    assert sess.trials[1].status == "aborted"
    assert "USB link lost" in sess.trials[1].abort_reason


class _Tty:
    def __init__(self, answer, tty=True):
        self.answer, self.tty = answer, tty

    def isatty(self):
        return self.tty

    def readline(self):
        return self.answer


def test_headless_confirmation_flag_terminal_and_no_terminal():
    import io

    from nmsid.rig.glitch_prompt import glitch_confirmation
    out = io.StringIO()
    auto = glitch_confirmation(True, stdin=_Tty("", tty=False), stdout=out)
    assert (auto("acquisition glitch", True), auto("acquisition glitch", False)) == (True, False)
    ask = glitch_confirmation(False, stdin=_Tty("y\n"), stdout=out)
    assert ask("stimulator glitch", True) is True
    assert glitch_confirmation(False, stdin=_Tty("\n"), stdout=out)("x", True) is False
    refuse = glitch_confirmation(False, stdin=_Tty("y\n", tty=False), stdout=out)
    assert refuse("x", True) is False
    assert "--resume" in out.getvalue()


def test_headless_without_a_confirmation_callback_ends_instead_of_waiting(tmp_path):
    """END_SESSION means no operator: a glitch between trials ends the session for
    --resume (it used to wait for a confirmation nobody could give, forever)."""
    path = tmp_path / "g.h5"
    rig = make_sim_rig(seed=1, faults=[_between_trials(FaultKind.STIM_DISCONNECT)])
    s = Engine(_cfg(), rig, path, trip_policy=TripPolicy.END_SESSION).run()
    assert s.n_completed == 1 and "session ended for --resume" in s.ended_by
    assert validate_session(path) == []
    assert not rig.world.output_active_at(rig.clock.monotonic_s())
