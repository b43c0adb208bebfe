"""MyoLeg participants (MuJoCo's MyoLeg at the knee and the ankle on a dynamometer):
the reduced model, the muscle groups on each channel and their signs, spill-over drawn per
participant, the torque in N m, the calibration in the joint's thresholds, determinism
under chunking and rollback, and the built-in model a session names.

Skipped only when the optional 'mujoco' extra (mujoco, myo_sim) is not installed."""

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("myo_sim")

from nmsid.protocols.config import ProtocolConfig  # noqa: E402
from nmsid.protocols.joints import JOINTS  # noqa: E402
from nmsid.protocols.waveforms import currents_mA, rE_signal  # noqa: E402
from nmsid.sim_backends.errors import SimConfigError  # noqa: E402
from nmsid.sim_backends.msk_leg import (  # noqa: E402
    default_leg_participant,
    make_leg_population,
)
from nmsid.sim_backends.msk_participant import MskParticipant  # noqa: E402
from nmsid.sim_backends.msk_physics import MUSCLE_GROUPS, MuscleFatigue  # noqa: E402
from nmsid.sim_backends.msk_simulation import MskSimulator  # noqa: E402
from nmsid.sim_backends.participant_models import participant_for_model  # noqa: E402

LEG = ("knee", "ankle")


@pytest.fixture(scope="module", params=LEG)
def leg(request):
    return request.param, default_leg_participant(request.param, seed=2)


def _actuator(sim, name):
    import mujoco
    return mujoco.mj_name2id(sim.cm.model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)


def test_the_model_is_myoleg_reduced_to_the_joint(leg):
    joint, p = leg
    sim = MskSimulator(p)
    m = sim.cm.model
    ext, flex = MUSCLE_GROUPS[joint]
    import mujoco
    names = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)}
    assert names == set(ext + flex) | {"coactivation_stiffness"}
    joints = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(m.njnt)}
    # the knee keeps its coupled tibia / patella joints; the ankle is one hinge
    assert ("knee_angle_r" in joints) == (joint == "knee")
    assert ("ankle_angle_r" in joints) == (joint == "ankle")
    assert not any(j.endswith("_l") or j.startswith("hip") for j in joints)
    assert (m.nq == 1) == (joint == "ankle")
    # held at the protocol's posture (knee 60 deg of flexion, ankle neutral)
    assert np.degrees(sim.cm.q_fixture_rad) == pytest.approx(
        {"knee": 60.0, "ankle": 0.0}[joint])
    assert sim.cm.lever_m is None            # a dynamometer's torque, not a cuff force


def test_each_channel_drives_its_own_group_and_the_sign_is_the_joints(leg):
    joint, p = leg
    sim = MskSimulator(p)
    n = 4000
    I = np.full(n, 9.0)
    z = np.zeros(n)
    e = sim.excitation(I, z)
    ext, flex = MUSCLE_GROUPS[joint]
    for m_name in ext:           # the extensor electrode recruits its own group ...
        assert e[-1, _actuator(sim, m_name)] > 0.05, m_name
    ext_torque = MskSimulator(p).simulate(I, z).true_force_N[-1]
    flex_torque = MskSimulator(p).simulate(z, I).true_force_N[-1]
    # extension (knee) / plantarflexion (ankle) positive, in N m: beyond any elbow force
    assert ext_torque > JOINTS[joint].Fmin * 2 and flex_torque < -JOINTS[joint].Fmin * 2
    assert MskSimulator(p).simulate(z, z).true_force_N.max() == pytest.approx(0.0, abs=1e-6)


def test_the_excitation_goes_to_the_named_muscle(leg):
    # the model's actuator order differs from the drives' (extensors first): each drive's
    # command must land on its own muscle's actuator
    joint, p = leg
    sim = MskSimulator(p)
    I_e, I_f = np.linspace(0.0, 16.0, 50), np.linspace(16.0, 0.0, 50)
    e = sim.excitation(I_e, I_f)
    for d in p.drives:
        np.testing.assert_allclose(e[:, _actuator(sim, d.muscle)], d.command(I_e, I_f))
    assert sim.cm.drive_ctrl            # the orders do differ: the mapping is exercised


def test_spill_over_reaches_the_other_group_and_is_drawn_per_participant():
    pop = make_leg_population(3, seed=4, joint="knee")
    assert [q.code for q in pop] == ["K01", "K02", "K03"]
    assert make_leg_population(3, seed=4, joint="knee")[2] == pop[2]
    spills = {tuple(d.spill for d in q.drives) for q in pop}
    assert len(spills) == 3
    p = pop[0]
    ext, flex = MUSCLE_GROUPS["knee"]
    hamstring = next(d for d in p.drives if d.muscle == flex[0])
    # 16 mA on the quadriceps electrode reaches the hamstrings a little, 1 mA does not
    assert hamstring.command(np.array([16.0]), np.array([0.0]))[0] > 0
    assert hamstring.command(np.array([1.0]), np.array([0.0]))[0] == 0
    assert all(a.joint == "ankle" and a.code.startswith("A")
               for a in make_leg_population(2, seed=4, joint="ankle"))


def test_the_ramp_calibrates_in_the_joints_unit(leg):
    joint, p = leg
    cal = p.ramp_calibration()
    j = JOINTS[joint]
    assert (cal.Fmin_N, cal.Fmax_N) == (j.Fmin, j.Fmax)
    assert 1.0 <= cal.Iemin_mA < cal.Iemax_mA <= 16.0
    assert 1.0 <= cal.Ifmin_mA < cal.Ifmax_mA <= 16.0


def test_chunking_and_rollback_do_not_change_the_samples():
    p = default_leg_participant("knee", seed=3, fatigue=MuscleFatigue(tau_fatigue_s=20.0))
    cal = p.ramp_calibration()
    prot = ProtocolConfig(steady_s=0.5, chirp_s=1.0)
    I_e, I_f = currents_mA(rE_signal(prot), 0.7, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA,
                           cal.Ifmax_mA)
    one = MskSimulator(p).simulate(I_e, I_f)
    sim = MskSimulator(p)
    parts, k = [], 0
    for cut in (700, 1301, 2999):
        snap = sim.snapshot()
        sim.simulate(I_e[k:cut], I_f[k:cut])       # simulated once, rolled back, replayed
        sim.restore(snap)
        parts.append(sim.simulate(I_e[k:cut], I_f[k:cut]).force_N)
        k = cut
    np.testing.assert_array_equal(np.concatenate(parts), one.force_N[:k])


def test_sessions_name_it_as_the_built_in_musculoskeletal_model():
    for joint in LEG:
        p = participant_for_model("musculoskeletal", seed=3, joint=joint)
        assert isinstance(p, MskParticipant) and p.joint == joint and p.seed == 3
    with pytest.raises(SimConfigError, match="elbow, the knee and the ankle"):
        participant_for_model("musculoskeletal", joint="wrist")


def test_bad_leg_settings_are_refused():
    with pytest.raises(SimConfigError, match="valid: knee, ankle"):
        default_leg_participant("hip")
    knee = default_leg_participant("knee")
    with pytest.raises(SimConfigError, match="drives must be one MuscleDrive per muscle"):
        MskParticipant(drives=knee.drives)          # the elbow's muscles expected
    with pytest.raises(SimConfigError, match="lever_m"):
        MskSimulator(MskParticipant(joint="knee", drives=knee.drives))   # a cuff at a knee
