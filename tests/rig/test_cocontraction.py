"""Co-contraction sessions (rig/cocontraction.py): sE steps at a fixed rE, built from the
plan blocks and run by the one engine (docs/joints.md, docs/rig.md)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols.config import config_from_dict
from nmsid.protocols.plan import PlanRefused, cocontraction_plan
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.cocontraction import CoContractionSession
from nmsid.rig.engine import Engine
from nmsid.rig.observer import TripPolicy
from nmsid.rig.trials import session_kind_from_stored
from nmsid.sim_backends.faults import Fault, FaultKind
from nmsid.sim_backends.joint_participants import template_participant
from nmsid.sim_backends.rig import make_sim_rig

MANUAL = {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5, "Ifmax_mA": 8.0}
STEPS = (0.3, 0.5, 0.7, 0.9)


def _config(**interlock):
    return config_from_dict({"joint": "knee", "participant": "C01", "seed": 1,
                             "protocol": {"rest_s": 0.0},
                             "calibration": {"manual": MANUAL},
                             "interlock": interlock})


def _session(tmp_path, kind, faults=None, **interlock):
    rig = make_sim_rig(template_participant("knee", seed=3), faults=faults)
    path = tmp_path / "c.h5"
    summary = Engine(_config(**interlock), rig, path, session=kind,
                     trip_policy=TripPolicy.END_SESSION).run()
    return rig, path, summary


def test_plan_is_steps_at_one_rE():
    plan = cocontraction_plan(STEPS, 0.7, 3.0, repeats=2)
    assert plan.kind == "cocontraction" and len(plan) == 8
    assert [it.sE for it in plan] == list(STEPS) * 2
    assert {it.rE_range for it in plan} == {(0.7, 0.7)}
    assert [it.index for it in plan] == list(range(8))


@pytest.mark.parametrize("steps, rE, step_s, words", [
    ((0.3, 1.2), 0.5, 2.0, "sE = 1.2 is outside"),
    ((0.3,), 1.5, 2.0, "rE range"),
    ((0.3,), 0.5, float("inf"), "duration"),
])
def test_bad_sweep_refused_before_anything_stimulates(tmp_path, steps, rE, step_s, words):
    rig = make_sim_rig(template_participant("knee"))
    with pytest.raises(PlanRefused, match=words):
        Engine(_config(), rig, tmp_path / "x.h5", session=CoContractionSession(
            steps, rE, step_s, source="sweep.toml"))
    assert rig.max_sent_mA == (0.0, 0.0) and not (tmp_path / "x.h5").exists()


def test_sweep_runs_on_the_engine_and_torque_grows_with_coactivation(tmp_path):
    kind = CoContractionSession(STEPS, 0.7, 2.0)
    rig, path, summary = _session(tmp_path, kind)
    assert summary.trip is None
    assert validate_session(path) == []
    s = read_session(path)
    assert s.attrs["session_kind"] == "cocontraction" and s.attrs["joint"] == "knee"
    assert [t.sE for t in s.trials] == list(STEPS)
    held = []
    for t in s.trials:
        assert t.status == "completed" and t.n_samples == 4000
        assert np.all(t.rE == 0.7) and t.extra_attrs["trial_kind"] == "cocontraction"
        Ie = 2.0 + 0.7 * t.sE * 7.5                 # paper eqs. 1-4 at the fixed rE
        If = 1.5 + 0.3 * t.sE * 6.5
        assert np.allclose(t.I_ext_mA, Ie) and np.allclose(t.I_flex_mA, If)
        held.append(float(np.mean(t.force_N[2000:])))
    # rE 0.7 > 0.5: the extensor wins, and by more as both muscles are driven harder
    truth = [rig.participant.true_parameters(sE).Kp * 0.2 for sE in STEPS]
    assert np.all(np.diff(held) > 0)
    # the increments are the model's (the sensor's constant offset cancels)
    assert np.allclose(np.diff(held), np.diff(truth), rtol=0.05)
    assert rig.max_sent_mA[0] <= 9.5 and rig.max_sent_mA[1] <= 8.0


def test_estop_mid_step_ends_with_output_zero(tmp_path):
    kind = CoContractionSession(STEPS, 0.5, 2.0)
    rig, path, summary = _session(tmp_path, kind, [Fault(FaultKind.ESTOP, trial=1,
                                                         at_s=0.8)])
    assert summary.trip is not None and summary.trip.rule == "estop"
    assert validate_session(path) == []
    s = read_session(path)
    assert s.trials[-1].status == "aborted" and 0 < s.trials[-1].n_samples < 4000
    zero = [z for z in rig.output_zero_events if z.reason == "stop_now"]
    assert zero
    rec = rig.run_records[-1]
    I_e, I_f, _ = rig.world.output(rec.N_trigger, rec.N_trigger + 4000)
    stop = zero[0].sample_index - rec.N_trigger
    assert I_e[:stop].max() > 0 and not I_e[stop:].any() and not I_f[stop:].any()


def test_the_recorded_sweep_is_rebuilt_for_resume():
    kind = CoContractionSession(STEPS, 0.6, 2.5, repeats=2)
    back = session_kind_from_stored(kind.root_attrs(), "c.h5")
    assert isinstance(back, CoContractionSession)
    assert [(i.sE, i.rE_range, i.duration_s, i.repeat) for i in back.plan(None)] == \
        [(i.sE, i.rE_range, i.duration_s, i.repeat) for i in kind.plan(None)]
    with pytest.raises(Exception, match="cannot be read"):
        session_kind_from_stored({"session_kind": "cocontraction"}, "c.h5")


@settings(max_examples=200, deadline=None)
@given(sE=st.floats(1e-6, 1.0), rE=st.floats(0.0, 1.0),
       lo=st.tuples(st.floats(0.0, 20.0), st.floats(0.0, 20.0)),
       span=st.tuples(st.floats(0.01, 60.0), st.floats(0.01, 60.0)))
def test_a_step_never_commands_above_the_calibrated_maxima(sE, rE, lo, span):
    # the plan's envelope is the step's currents exactly, and the preflight passes it
    # against the calibration: a step is within (Imin, Imax] per channel by construction
    from nmsid.protocols.plan import RigLimits, preflight
    from nmsid.protocols.session_model import Calibration
    from nmsid.protocols.waveforms import currents_mA
    cal = Calibration(lo[0], lo[0] + span[0], lo[1], lo[1] + span[1])
    item = cocontraction_plan([sE], rE, 1.0)[0]
    Ie, If = currents_mA(np.array([rE]), sE, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA,
                         cal.Ifmax_mA)
    assert (float(Ie[0]), float(If[0])) == pytest.approx(item.max_current_mA(cal))
    assert Ie[0] <= cal.Iemax_mA + 1e-9 and If[0] <= cal.Ifmax_mA + 1e-9
    preflight(cocontraction_plan([sE], rE, 1.0), RigLimits(100.0, 100.0, 25.0), cal)


def test_an_interrupted_sweep_resumes_as_recorded(tmp_path):
    # E-stop in the second step, then --resume's path: the kind is rebuilt from the file
    # (a file names a kind, never code), the aborted step is run again, the rest follow
    kind = CoContractionSession(STEPS, 0.6, 1.5)
    rig, path, summary = _session(tmp_path, kind, [Fault(FaultKind.ESTOP, trial=1,
                                                         at_s=0.5)])
    assert summary.trip is not None
    attrs = read_session(path).attrs
    again = session_kind_from_stored(attrs, str(path))
    eng = Engine(None, make_sim_rig(template_participant("knee", seed=3)), path,
                 resume=True, session=again, trip_policy=TripPolicy.END_SESSION)
    eng.run()
    s = read_session(path)
    done = [t for t in s.trials if t.status == "completed"]
    assert sorted(t.sE for t in done) == sorted(STEPS)
    assert all(np.all(t.rE == 0.6) for t in s.trials)
    assert validate_session(path) == []
