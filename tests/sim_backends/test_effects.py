"""Each optional effect does what its formula in docs/twin-file.md says."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from nmsid.errors import UserError
from nmsid.protocols.effects import EffectParamError
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import currents_for, ramp_thresholds, run_waveform, waveform
from nmsid.sim_backends.effects import (
    EFFECT_NAMES,
    ActivationDynamics,
    BaselineDrift,
    DeadTime,
    Fatigue,
    FlexorExtensorAsymmetry,
    RecruitmentNonlinearity,
    effect_from_dict,
    effects_from_list,
    effects_to_list,
)
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.filters import second_order_zoh
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.sensor import SensorModel

FS = 2000.0
ATOL_N = 2e-3


def _ideal(*effects):
    return default_participant(sensor=SensorModel.ideal()).with_effects(*effects)


def _trial(p, sE, rE, rig=None):
    rig = rig or make_sim_rig(p)
    if rig.stimulator.status().state.value == "disconnected":
        rig.stimulator.connect()
    I_e, I_f = currents_for(p.calibration, sE, rE)
    force, _ = run_waveform(rig, waveform(I_e, I_f))
    return force, rig


def _step_rE(n_s=3.0, at_s=1.0, level=0.8):
    rE = np.full(int(n_s * FS), 0.5)
    rE[int(at_s * FS):] = level
    return rE


def _fit_sine(force, t, w, keep):
    X = np.column_stack([np.sin(w * t[keep]), np.cos(w * t[keep])])
    (s, c), *_ = np.linalg.lstsq(X, force[keep], rcond=None)
    return math.hypot(s, c), math.atan2(c, s)


@pytest.mark.parametrize("L_s", [0.025, 0.0123])
def test_dead_time_shifts_the_response_by_L(L_s):
    rE = _step_rE()
    nominal, _ = _trial(_ideal(), 0.6, rE)
    delayed, _ = _trial(_ideal(DeadTime(L_s)), 0.6, rE)
    d = L_s * FS
    k, frac = int(d), d - int(d)
    shifted = np.concatenate([np.zeros(k + 1), nominal])[1:][:nominal.size]   # x[n-k]
    shifted1 = np.concatenate([np.zeros(k + 1), nominal])[:nominal.size]      # x[n-k-1]
    expected = (1 - frac) * shifted + frac * shifted1
    assert np.max(np.abs(delayed - expected)) < 1e-9
    assert np.max(np.abs(delayed[:k])) < 1e-12


@pytest.mark.parametrize("tau_s", [0.01, 0.04])
def test_activation_lag_adds_phase_atan_w_tau(tau_s):
    sE, a, f_Hz = 0.7, 0.3, 4.0
    w = 2 * np.pi * f_Hz
    t = np.arange(int(6 * FS)) / FS
    rE = 0.5 + a * np.sin(w * t)
    keep = t > 2.5
    g0, ph0 = _fit_sine(_trial(_ideal(), sE, rE)[0], t, w, keep)
    g1, ph1 = _fit_sine(_trial(_ideal(ActivationDynamics(tau_s)), sE, rE)[0], t, w, keep)
    assert g1 / g0 == pytest.approx(1 / math.sqrt(1 + (w * tau_s) ** 2), rel=2e-3)
    assert ph0 - ph1 == pytest.approx(math.atan(w * tau_s), abs=2e-3)


@pytest.mark.parametrize("shape", ["exponential", "linear"])
def test_fatigue_gain_follows_cumulative_stimulation(shape):
    fat = Fatigue(shape, gain_loss_pct=40.0, reference_stim_s=10.0)
    rE = _step_rE(n_s=4.0, at_s=0.5)
    p0, p1 = _ideal(), _ideal(fat)
    rig0, rig1 = make_sim_rig(p0), make_sim_rig(p1)
    for trial in range(3):          # the participant keeps its state across trials
        f0, _ = _trial(p0, 0.6, rE, rig0)
        f1, _ = _trial(p1, 0.6, rE, rig1)
        c = trial * 4.0 + np.arange(1, rE.size + 1) / FS    # seconds of stimulation so far
        g = fat.gain(c)
        assert np.max(np.abs(f1 - g * f0)) < 1e-9
    c_end = 12.0
    expected = 0.6 ** (c_end / 10.0) if shape == "exponential" else max(0.05, 1 - 0.4 * 1.2)
    assert fat.gain(c_end) == pytest.approx(expected)
    assert rig1.cumulative_stim_s == pytest.approx(12.0)


shapes = st.one_of(
    st.builds(lambda g: RecruitmentNonlinearity("power", gamma=g), st.floats(0.3, 4.0)),
    st.builds(lambda s, m: RecruitmentNonlinearity("sigmoid", slope=s, midpoint=m),
              st.floats(0.5, 30.0), st.floats(-0.5, 1.5)),
    st.builds(lambda a, b: RecruitmentNonlinearity("threshold_saturation", threshold=min(a, b),
                                                   saturation=max(a, b) + 0.01),
              st.floats(0.0, 0.6), st.floats(0.0, 0.95)))


@settings(max_examples=60, deadline=None)
@given(shapes)
def test_recruitment_maps_0_to_0_and_1_to_1_monotonically(rec):
    x = np.linspace(0, 1, 201)
    h = rec.h(x)
    assert h[0] == pytest.approx(0.0, abs=1e-12) and h[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(h) >= -1e-12)


def test_recruitment_nonlinearity_shapes_the_static_force():
    rec = RecruitmentNonlinearity("power", gamma=2.0)
    p = _ideal(rec)
    sE = 0.8
    for rE_level in (0.2, 0.5, 0.9):
        force, _ = _trial(p, sE, _step_rE(n_s=2.5, at_s=0.0, level=rE_level))
        k = p.Kp(sE) / (2 * sE)
        u_e, u_f = rE_level * sE, (1 - rE_level) * sE
        assert force[-1] == pytest.approx(k * (u_e ** 2 - u_f ** 2), abs=ATOL_N)


def test_asymmetry_gives_the_sum_of_two_second_order_responses():
    asym = FlexorExtensorAsymmetry(wn_ratio=0.6, zeta_ratio=1.5)
    p = _ideal(asym)
    sE = 0.6
    rE = _step_rE()
    force, _ = _trial(p, sE, rE)
    _, wn, zeta = p.true_parameters(sE)
    k = p.Kp(sE) / (2 * sE)
    f_e = p.calibration.Fmin_N + k * rE * sE          # each muscle's static force
    f_f = p.calibration.Fmin_N + k * (1 - rE) * sE
    b1, a1 = second_order_zoh(wn, zeta, FS)
    b2, a2 = second_order_zoh(wn * 0.6, zeta * 1.5, FS)
    expected = signal.lfilter(b1, a1, f_e) - signal.lfilter(b2, a2, f_f)
    assert np.max(np.abs(force - expected)) < ATOL_N
    assert force[-1] == pytest.approx(p.Kp(sE) * 0.3, abs=ATOL_N)   # same static gain


def test_baseline_drift_is_band_limited_with_the_given_rms():
    drift = BaselineDrift(amplitude_N=0.2, corner_Hz=0.5)
    p = _ideal(drift)
    rig = make_sim_rig(p)
    rig.stimulator.connect()
    n = int(200 * FS)
    force, _ = run_waveform(rig, waveform(np.zeros(n), np.zeros(n)))
    assert np.sqrt(np.mean(force ** 2)) == pytest.approx(0.2, rel=0.2)
    spec = np.abs(np.fft.rfft(force)) ** 2
    f = np.fft.rfftfreq(n, 1 / FS)
    assert spec[f > 0.5].sum() < 0.01 * spec.sum()
    again, _ = run_waveform(make_sim_rig(p, connect=True), waveform(np.zeros(n), np.zeros(n)))
    assert np.array_equal(force, again)                       # seeded
    other = default_participant(seed=9, sensor=SensorModel.ideal()).with_effects(drift)
    f9, _ = run_waveform(make_sim_rig(other, connect=True), waveform(np.zeros(n), np.zeros(n)))
    assert not np.allclose(force, f9)


def test_several_effects_at_once_and_the_ramp_still_finds_the_calibration():
    p = default_participant(seed=2).with_effects(
        DeadTime(0.02), ActivationDynamics(0.03), Fatigue("linear", 20.0),
        RecruitmentNonlinearity("sigmoid", slope=8.0, midpoint=0.4),
        FlexorExtensorAsymmetry(1.3, 0.8), BaselineDrift(0.02, 0.1))
    assert sorted(e["name"] for e in p.effect_truth()) == sorted(EFFECT_NAMES)
    assert p.ramp_calibration() == p.calibration
    rig = make_sim_rig(p, connect=True)
    assert ramp_thresholds(rig, "ext") == (p.calibration.Iemin_mA, p.calibration.Iemax_mA)


def test_effect_parsing_round_trips_and_refuses_unknowns():
    items = [{"name": "dead_time", "params": {"L_s": 0.03}},
             {"name": "fatigue", "params": {"shape": "linear", "gain_loss_pct": 25.0,
                                            "reference_stim_s": 675.0}},
             {"name": "recruitment_nonlinearity",
              "params": {"shape": "threshold_saturation", "threshold": 0.1,
                         "saturation": 0.9}},
             {"name": "baseline_drift", "params": {"amplitude_N": 0.1, "corner_Hz": 0.2}},
             {"name": "flexor_extensor_asymmetry", "params": {"wn_ratio": 1.2,
                                                              "zeta_ratio": 0.9}},
             {"name": "activation_dynamics", "params": {"tau_s": 0.05}}]
    assert effects_to_list(effects_from_list(items)) == items
    with pytest.raises(SimConfigError, match="valid: .*dead_time"):
        effect_from_dict({"name": "refractory", "params": {}})
    with pytest.raises(SimConfigError, match="unknown params"):
        effect_from_dict({"name": "dead_time", "params": {"L": 0.03}})
    with pytest.raises(SimConfigError, match="gamma"):
        effect_from_dict({"name": "recruitment_nonlinearity", "params": {"shape": "power"}})
    with pytest.raises(SimConfigError, match="more than once"):
        effects_from_list([items[0], items[0]])
    # built directly, the registry's dataclass refuses with its own user error (exit 2)
    with pytest.raises(EffectParamError, match="L_s"):
        DeadTime(-1.0)
    assert issubclass(EffectParamError, UserError)
