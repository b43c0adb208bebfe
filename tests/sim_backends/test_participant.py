"""The nominal participant against closed-form second-order answers, and its ground truth."""

import math

import numpy as np
import pytest
from scipy import signal

from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import (
    chirp_rE,
    currents_for,
    ramp_thresholds,
    run_waveform,
    waveform,
)
from nmsid.sim_backends.filters import second_order_zoh
from nmsid.sim_backends.participant import ReferenceCalibration, default_participant
from nmsid.sim_backends.population import make_population
from nmsid.sim_backends.sensor import SensorModel

FS = 2000.0
ATOL_N = 2e-3   # 1 uA current quantisation moves rE by ~2e-4: Kp * 2e-4 < 2e-3 N


def _step_response(t, Kp, wn, zeta):
    wd = wn * math.sqrt(1 - zeta ** 2)
    return Kp * (1 - np.exp(-zeta * wn * t) * (np.cos(wd * t)
                                               + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t)))


def _run(participant, sE, rE, **kw):
    rig = make_sim_rig(participant, **kw)
    rig.stimulator.connect()
    I_e, I_f = currents_for(participant.calibration, sE, rE)
    force, _ = run_waveform(rig, waveform(I_e, I_f))
    return force, rig


@pytest.mark.parametrize("sE", [0.3, 0.65, 1.0])
def test_step_response_is_the_analytic_second_order_step(ideal_participant, sE):
    n0 = int(2 * FS)
    rE = np.full(int(5 * FS), 0.5)
    rE[n0:] = 0.8
    force, _ = _run(ideal_participant, sE, rE)
    Kp, wn, zeta = ideal_participant.true_parameters(sE)
    t = np.arange(rE.size - n0) / FS
    expected = _step_response(t, Kp * 0.3, wn, zeta)
    assert np.max(np.abs(force[:n0])) < ATOL_N          # rE = 0.5: balanced, no force
    assert np.max(np.abs(force[n0:] - expected)) < ATOL_N
    assert force[-1] == pytest.approx(Kp * 0.3, abs=ATOL_N)


@pytest.mark.parametrize("f_Hz", [1.5, 6.0])
def test_sine_gain_and_phase_match_the_transfer_function(ideal_participant, f_Hz):
    sE, a = 0.8, 0.3
    t = np.arange(int(8 * FS)) / FS
    rE = 0.5 + a * np.sin(2 * np.pi * f_Hz * t)
    force, _ = _run(ideal_participant, sE, rE)
    Kp, wn, zeta = ideal_participant.true_parameters(sE)
    w = 2 * np.pi * f_Hz
    G = Kp * wn ** 2 / (wn ** 2 - w ** 2 + 2j * zeta * wn * w)
    keep = t > 3.0                                   # transient gone
    X = np.column_stack([np.sin(w * t[keep]), np.cos(w * t[keep])])
    (s, c), *_ = np.linalg.lstsq(X, force[keep], rcond=None)
    gain = math.hypot(s, c) / a
    phase = math.atan2(c, s)
    # the stimulator holds each sample: ZOH adds half a sample of delay
    expected_phase = np.angle(G) - w / (2 * FS)
    assert gain == pytest.approx(abs(G), rel=2e-3)
    assert phase == pytest.approx(expected_phase, abs=2e-3)


def test_chirp_trial_is_exactly_the_twin_model(ideal_participant):
    sE = 0.45
    rE = chirp_rE()
    force, _ = _run(ideal_participant, sE, rE)
    Kp, wn, zeta = ideal_participant.true_parameters(sE)
    b, a = second_order_zoh(wn, zeta, FS)
    twin = signal.lfilter(b, a, Kp * (rE - 0.5))
    assert np.max(np.abs(force - twin)) < ATOL_N


def test_true_parameters_follow_the_curves_and_are_tuples():
    p = default_participant()
    for sE in np.arange(0.3, 1.001, 0.05):
        tp = p.true_parameters(sE)
        Kp, wn, zeta = tp
        assert Kp == pytest.approx(p.Kp(sE)) and wn == pytest.approx(p.wn_rad_s(sE))
        assert zeta == pytest.approx(p.zeta(sE))
        assert 2 <= Kp <= 15 and 10 <= wn <= 50 and 0.3 <= zeta <= 1.0


def test_true_parameters_for_another_calibration_predict_the_trial():
    """A hand-entered calibration with both spans widened by 20 %: the muscles' own
    co-activation and gain differ from the commanded sE, and true_parameters says how."""
    p = default_participant(sensor=SensorModel.ideal())
    ref = p.calibration
    other = ReferenceCalibration(ref.Iemin_mA, ref.Iemin_mA + 1.2 * (ref.Iemax_mA - ref.Iemin_mA),
                                 ref.Ifmin_mA, ref.Ifmin_mA + 1.2 * (ref.Ifmax_mA - ref.Ifmin_mA))
    sE = 0.5
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    n0 = int(1 * FS)
    rE = np.full(int(4 * FS), 0.5)
    rE[n0:] = 0.7
    I_e, I_f = currents_for(other, sE, rE)
    force, _ = run_waveform(rig, waveform(I_e, I_f))
    Kp, wn, zeta = p.true_parameters(sE, other)
    # u_e = u_f = 0.5 * 1.2 * sE = 0.3 -> own sE 0.6, gain k(0.6) = Kp(0.6) / 1.2, and
    # d(u_e - u_f)/drE = 2 * 1.2 * sE = 1.2 -> Kp = Kp(0.6)
    assert Kp == pytest.approx(p.Kp(0.6), rel=1e-9)
    t = np.arange(rE.size - n0) / FS
    expected = _step_response(t, Kp * 0.2, wn, zeta)
    assert np.max(np.abs(force[n0:] - expected)) < ATOL_N
    # the participant's own co-activation is 1.2 sE
    assert wn == pytest.approx(p.wn_rad_s(0.6)) and zeta == pytest.approx(p.zeta(0.6))


def test_noise_levels_are_as_configured():
    p = default_participant(sensor=SensorModel(noise_N=0.05, offset_N=0.0, drift_N_per_s=0.0,
                                               mains_N=0.0))
    force, _ = _run(p, 0.5, np.full(int(4 * FS), 0.5))
    assert np.std(force) == pytest.approx(0.05, rel=0.05)


def test_population_is_reproducible_and_varied():
    pop = make_population(10, seed=3)
    assert pop == make_population(10, seed=3)
    assert make_population(4, seed=3) == pop[:4]
    assert pop != make_population(10, seed=4)
    grid = np.linspace(0.3, 1.0, 15)
    inside_peaks = 0
    for p in pop:
        kp = p.Kp(grid)
        wn = p.wn_rad_s(grid)
        z = p.zeta(grid)
        assert np.all(np.diff(kp) > 0) and 2.0 <= kp.min() and kp.max() <= 15
        assert 10 <= wn.min() and wn.max() <= 50 and 0.3 <= z.min() and z.max() <= 1.0
        inside_peaks += int(0 < np.argmax(wn) < 14)
        assert 0.02 <= p.sensor.noise_N <= 0.06
        assert p.ramp_calibration() == p.calibration
    assert {p.Kp.model for p in pop} | {p.wn_rad_s.model for p in pop} != set()
    assert 0 < inside_peaks < 10       # some extrema inside the range, some outside
    assert len({round(p.sensor.noise_N, 4) for p in pop}) == 10


@pytest.mark.parametrize("who", ["default", "S02", "S07"])
def test_calibration_ramp_finds_the_designed_currents(who):
    if who == "default":
        p = default_participant(seed=5)
    else:
        p = {q.code: q for q in make_population(8, seed=11)}[who]
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    cal = p.calibration
    assert ramp_thresholds(rig, "ext") == (cal.Iemin_mA, cal.Iemax_mA)
    assert ramp_thresholds(rig, "flex") == (cal.Ifmin_mA, cal.Ifmax_mA)
    # what the ramp finds is what the participant's ground truth is defined for
    assert p.ramp_calibration() == cal


def test_single_muscle_recruitment_is_piecewise_linear_threshold_to_saturation():
    p = default_participant()
    cal = p.calibration
    I = np.linspace(0, 16, 3201)
    for m in ("ext", "flex"):
        f = p.single_muscle_force_N(m, I)
        assert f[0] == 0 and np.all(np.diff(f) >= -1e-12)
        slope = (cal.Fmax_N - cal.Fmin_N) / cal.span_mA(m)
        inside = (I > cal.imin_mA(m)) & (I < cal.imin_mA(m) + cal.span_mA(m))
        assert np.allclose(np.diff(f)[inside[:-1] & inside[1:]] / (I[1] - I[0]), slope)
        assert f[-1] == pytest.approx(f.max()) and np.ptp(f[-50:]) == 0   # saturated


def test_rounding_below_imin_at_rE_0_or_1_does_not_change_regime(ideal_participant):
    """rE = 1 puts the flexor exactly at Ifmin; a current a few uA below (rounding in a
    waveform generator) must not switch the muscle to its single-muscle recruitment."""
    p = ideal_participant
    sE = 0.7
    rE = np.full(int(1.0 * FS), 1.0)
    I_e, I_f = currents_for(p.calibration, sE, rE)
    clean, _ = _run_currents(p, I_e, I_f)
    I_f2 = I_f.copy()
    I_f2[::3] -= 0.004                      # 4 uA below Imin on every third sample
    rough, _ = _run_currents(p, I_e, I_f2)
    assert np.max(np.abs(rough - clean)) < 2e-3


def _run_currents(p, I_e, I_f):
    rig = make_sim_rig(p, connect=True)
    return run_waveform(rig, waveform(I_e, I_f))


def test_truth_holds_for_an_sE_off_the_protocol_grid(ideal_participant):
    p = ideal_participant
    sE = 0.4567891
    n0 = int(1 * FS)
    rE = np.full(int(4 * FS), 0.5)
    rE[n0:] = 0.75
    force, _ = _run(p, sE, rE)
    Kp, wn, zeta = p.true_parameters(sE)
    expected = _step_response(np.arange(rE.size - n0) / FS, Kp * 0.25, wn, zeta)
    assert np.max(np.abs(force[n0:] - expected)) < 5e-4


def test_population_families_come_in_the_papers_proportions():
    from collections import Counter
    pop = make_population(20, seed=8)
    for block in (pop[:10], pop[10:]):
        assert Counter(p.Kp.model.value for p in block) == {"linear": 4, "exponential": 5,
                                                            "quadratic": 1}
        assert Counter(p.wn_rad_s.model.value for p in block) == {
            "linear": 2, "exponential": 3, "quadratic": 5}
        assert Counter(p.zeta.model.value for p in block) == {
            "quadratic": 2, "exponential": 4, "linear": 4}
