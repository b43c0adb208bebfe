"""The musculoskeletal participant (MuJoCo elbow): interface, determinism, physics, truth.

Skipped only when the optional 'mujoco' extra (mujoco, myo_sim) is not installed."""

import inspect
import math

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("myo_sim")

from nmsid.protocols.config import ProtocolConfig  # noqa: E402
from nmsid.protocols.waveforms import currents_mA, rE_signal  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402
from nmsid.sim_backends.msk_participant import MskParticipant, default_msk_participant  # noqa: E402
from nmsid.sim_backends.msk_physics import MuscleFatigue  # noqa: E402
from nmsid.sim_backends.msk_population import make_msk_population  # noqa: E402
from nmsid.sim_backends.msk_simulation import MskSimulator  # noqa: E402
from nmsid.sim_backends.msk_truth import fit_second_order_reference  # noqa: E402
from nmsid.sim_backends.participant import TrueParameters  # noqa: E402
from nmsid.sim_backends.sensor import SensorModel  # noqa: E402
from nmsid.sim_backends.simulation import ParticipantSimulator  # noqa: E402

SHORT = ProtocolConfig(steady_s=1.0, chirp_s=3.0)


def _trial_currents(p, sE=0.6, protocol=SHORT):
    cal = p.ramp_calibration()
    return currents_mA(rE_signal(protocol), sE, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA,
                       cal.Ifmax_mA)


def test_simulator_has_the_template_simulators_interface():
    sim = MskSimulator(default_msk_participant())
    for name, member in inspect.getmembers(ParticipantSimulator):
        if name.startswith("_") or name == "operating_point":
            continue
        assert hasattr(sim, name), name
        if inspect.isfunction(member):
            want = list(inspect.signature(member).parameters)
            assert list(inspect.signature(getattr(sim, name)).parameters) == want[1:], name
    assert hasattr(sim, "cursor") and hasattr(sim, "stim_samples")
    p = default_msk_participant()
    for attr in ("code", "seed", "sensor", "true_parameters", "effect_truth"):
        assert hasattr(p, attr)
    rig = make_sim_rig(p)
    assert rig.participant is p and isinstance(rig.world.sim, MskSimulator)


@pytest.mark.parametrize("fatigue", [MuscleFatigue(), MuscleFatigue(tau_fatigue_s=20.0)])
def test_chunking_and_rollback_do_not_change_the_samples(fatigue):
    p = default_msk_participant(seed=3, fatigue=fatigue)
    I_e, I_f = _trial_currents(p)
    one = MskSimulator(p).simulate(I_e, I_f)
    sim = MskSimulator(p)
    rng = np.random.default_rng(0)
    parts, k = [], 0
    while k < I_e.size:
        m = int(rng.integers(1, 1500))
        parts.append(sim.simulate(I_e[k:k + m], I_f[k:k + m]).force_N)
        k += m
    np.testing.assert_array_equal(np.concatenate(parts), one.force_N)
    # roll back to a snapshot and replay: the same samples again
    sim2 = MskSimulator(p)
    sim2.simulate(I_e[:3000], I_f[:3000])
    snap = sim2.snapshot()
    a = sim2.simulate(I_e[3000:], I_f[3000:]).force_N
    sim2.simulate(np.zeros(500), np.zeros(500))
    sim2.restore(snap)
    b = sim2.simulate(I_e[3000:], I_f[3000:]).force_N
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, one.force_N[3000:])


def test_rest_reads_zero_and_a_rest_returns_to_it():
    p = default_msk_participant(sensor=SensorModel.ideal())
    sim = MskSimulator(p)
    z = np.zeros(2000)
    assert np.max(np.abs(sim.simulate(z, z).true_force_N)) < 1e-9   # tared at rest
    I = np.full(2000, 7.0)
    f = sim.simulate(I, z).true_force_N
    assert f[-1] > 1.0                    # the extensor pushes: extension positive
    assert not sim.at_rest()
    sim.advance_quiet(30000)
    assert sim.at_rest() and sim.cursor == 36000 - 2000
    g = MskSimulator(p).simulate(z, I).true_force_N
    assert g[-1] < -1.0                   # the flexor pulls


def test_fatigue_follows_its_state_and_recovers():
    fat = MuscleFatigue(tau_fatigue_s=30.0, tau_recovery_s=60.0, min_fraction=0.4)
    p = default_msk_participant(sensor=SensorModel.ideal(), fatigue=fat)
    sim = MskSimulator(p)
    n = 60 * 2000
    I_e = np.full(n, 9.0)
    f = sim.simulate(I_e, np.zeros(n)).true_force_N
    # the extensor heads' state follows the closed form of their constant drive
    ctrl = sim.excitation(np.array([9.0]), np.array([0.0]))[0, :6]
    reach = np.array([d.own.max_activation + d.spill.max_activation for d in p.drives])
    want = fat.step(np.ones(6), ctrl / reach, 60.0)
    np.testing.assert_allclose(sim.force_scale, want, rtol=1e-9)
    early, late = f[2000:4000].mean(), f[-2000:].mean()
    assert late < 0.8 * early
    # the force follows the state, roughly (static isometric force ~ active force)
    assert late / early == pytest.approx(float(np.mean(want[:3])) / float(
        np.mean(fat.step(np.ones(6), ctrl / reach, 2.0)[:3])), rel=0.1)
    sim.advance_quiet(120 * 2000)
    assert np.all(sim.force_scale > want) and np.all(sim.force_scale < 1)


def test_population_is_reproducible_from_its_seed():
    a = make_msk_population(4, seed=7)
    assert a == make_msk_population(4, seed=7)
    assert a[:2] == make_msk_population(2, seed=7)
    assert a[0] != make_msk_population(1, seed=8)[0]
    assert len({p.mount for p in a}) == 4 and len({p.seed for p in a}) == 4
    assert all(not p.fatigue.enabled for p in a)
    assert all(p.fatigue.enabled for p in make_msk_population(2, seed=7, fatigue=True))
    # same participant, same samples (MuJoCo and the sensor noise are deterministic)
    I_e, I_f = _trial_currents(a[1], 0.5, ProtocolConfig(steady_s=0.5, chirp_s=1.0))
    np.testing.assert_array_equal(MskSimulator(a[1]).simulate(I_e, I_f).force_N,
                                  MskSimulator(make_msk_population(2, 7)[1])
                                  .simulate(I_e, I_f).force_N)


def test_population_members_look_like_the_papers_participants():
    for p in make_msk_population(3, seed=2):
        cal = p.ramp_calibration()
        assert 1.0 <= cal.Iemin_mA < cal.Iemax_mA <= 16 and 1.0 <= cal.Ifmin_mA < cal.Ifmax_mA <= 16
        lo, hi = (p.second_order_truth(s, cal) for s in (0.3, 1.0))
        assert 0 < lo.Kp < hi.Kp                           # gain grows with co-activation
        for t in (lo, hi):
            assert 8 < t.wn_rad_s < 45 and 0.2 < t.zeta < 1.3, t
            assert 60 < t.fit_pct < 99.5, t                # roughly, not exactly, 2nd order


def test_reference_fit_recovers_a_known_second_order_system():
    from scipy import signal
    fs = 2000.0
    p = ProtocolConfig(steady_s=0.0, chirp_s=6.0)
    u = rE_signal(p) - 0.5
    rng = np.random.default_rng(1)
    for Kp, wn, z in ((3.0, 20.0, 0.4), (8.0, 35.0, 0.9), (1.2, 12.0, 0.25)):
        t = np.arange(u.size) / fs
        y = signal.lsim(([Kp * wn ** 2], [1, 2 * z * wn, wn ** 2]), u, t,
                        X0=rng.normal(0, 0.05, 2))[1]
        y = y + 0.3 + 0.02 * t                             # offset and ramp are estimated
        Kp_h, wn_h, z_h, fit = fit_second_order_reference(u, y, fs)
        assert Kp_h == pytest.approx(Kp, rel=2e-3)
        assert wn_h == pytest.approx(wn, rel=2e-3)
        assert z_h == pytest.approx(z, rel=2e-3)
        assert fit > 99.5


def test_true_parameters_are_the_truths_first_three():
    p = default_msk_participant()
    t = p.second_order_truth(0.5)
    assert p.true_parameters(0.5) == TrueParameters(t.Kp, t.wn_rad_s, t.zeta)
    assert p.effect_truth() == []
    assert math.isfinite(t.offset_N)


def test_bad_participant_settings_are_refused():
    from nmsid.sim_backends.errors import SimConfigError
    with pytest.raises(SimConfigError, match="code"):
        MskParticipant(code="not ok")
    with pytest.raises(SimConfigError, match="tau_act_s"):
        MskParticipant(tau_act_s=2.0)
    with pytest.raises(SimConfigError, match="drives"):
        MskParticipant(drives=default_msk_participant().drives[::-1])


def test_coactivation_stiffens_the_endpoint_dynamics():
    from nmsid.sim_backends.msk_physics import CoactivationStiffness
    bare = default_msk_participant(stiffening=CoactivationStiffness(gamma=0.0))
    stiff = default_msk_participant(stiffening=CoactivationStiffness(gamma=12.0))
    sim = MskSimulator(stiff)
    e = sim.excitation(np.array([7.0]), np.array([5.0]))
    # the stiffness control is gamma r^2 F0 / L0 per unit excitation, linear in gamma
    np.testing.assert_allclose(e[:, 6], e[:, :6] @ sim.cm.srs_Nm_rad)
    np.testing.assert_allclose(MskSimulator(bare).cm.srs_Nm_rad, 0.0)
    assert np.all(sim.cm.srs_Nm_rad > 0)
    cal = bare.ramp_calibration()
    w_bare = [bare.second_order_truth(s, cal, SHORT).wn_rad_s for s in (0.3, 1.0)]
    w_stiff = [stiff.second_order_truth(s, cal, SHORT).wn_rad_s for s in (0.3, 1.0)]
    # without it wn hardly moves with co-activation; with it wn rises with sE
    assert abs(w_bare[1] / w_bare[0] - 1) < 0.02
    assert w_stiff[1] > w_stiff[0] * 1.02 and w_stiff[1] > w_bare[1]


def test_trial_variant_moves_the_parameter_its_physics_drives():
    """gain -> Kp, speed -> wn, damping -> zeta, each mostly on its own; 1 changes nothing."""
    from nmsid.sim_backends.errors import SimConfigError
    p = default_msk_participant()
    cal = p.ramp_calibration()
    assert p.trial_variant() == p

    def rel(q):
        a, b = q.second_order_truth(0.6, cal, SHORT), p.second_order_truth(0.6, cal, SHORT)
        return np.array([a.Kp / b.Kp, a.wn_rad_s / b.wn_rad_s, a.zeta / b.zeta]) - 1

    for j, kw in enumerate(({"gain": 1.1}, {"speed": 1.05}, {"damping": 1.05})):
        r = rel(p.trial_variant(**kw))
        assert r[j] > 0.025, (kw, r)                            # the one it is meant for
        assert abs(r[j]) > 1.5 * np.max(np.abs(np.delete(r, j))), (kw, r)
    assert p.trial_variant(gain=0.9).drives[0].own.max_activation == pytest.approx(
        0.9 * p.drives[0].own.max_activation)
    with pytest.raises(SimConfigError, match="gain"):
        p.trial_variant(gain=0.0)
