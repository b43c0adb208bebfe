"""The input-timing model: fixed settings, the estimate on closed-form signals (either
sign), and the simulated rig's held samples no longer flagged by the residual tests."""

import numpy as np
import pytest
from scipy import signal

from nmsid.analysis.errors import SettingError
from nmsid.analysis.identify import identify_level
from nmsid.analysis.input_timing import estimate_session_timing, fixed_timing, pooled
from nmsid.analysis.preprocess import fixed_delay_s
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.session_file import Trial

FS = 2000.0
STEADY_S, CHIRP_S = 5.0, 10.0


def _chirp(t):
    tc = np.clip(t - STEADY_S, 0.0, None)
    k = 10.0
    phase = 2 * np.pi * CHIRP_S / np.log(k) * (k ** (tc / CHIRP_S) - 1)
    return np.where(t >= STEADY_S, 0.5 + 0.5 * np.sin(phase), 0.5)


def _trials(delay_s, *, levels=(0.4, 0.7, 1.0), repeats=2, noise_N=0.005, seed=0):
    """Exact response of Kp wn^2/(s^2 + 2 zeta wn s + wn^2) to the chirp delayed by
    ``delay_s`` (the stimulation), simulated on a 10x finer grid; the record is the chirp
    itself."""
    rng = np.random.default_rng(seed)
    n = int((STEADY_S + CHIRP_S) * FS)
    t = np.arange(n) / FS
    up = 10
    tf = np.arange(n * up) / (FS * up)
    out = []
    for sE in levels:
        Kp, wn, zeta = 2 + 3 * sE, 25 + 20 * sE, 0.4 + 0.3 * sE
        u = _chirp(tf - delay_s) - 0.5
        _, y, _ = signal.lsim(([Kp * wn ** 2], [1, 2 * zeta * wn, wn ** 2]), u, tf)
        for r in range(1, repeats + 1):
            force = y[::up] + noise_N * rng.standard_normal(n) + 0.2
            out.append(Trial(sE=sE, repeat=r, fs_Hz=FS, rE=_chirp(t), I_ext_mA=np.zeros(n),
                             I_flex_mA=np.zeros(n), force_N=force, steady_s=STEADY_S,
                             chirp_s=CHIRP_S))
    return out


@pytest.mark.parametrize("delay_s", [-0.4e-3, 0.3e-3, 0.7e-3])
def test_delay_of_either_sign_is_estimated(delay_s):
    est = estimate_session_timing(_trials(delay_s))
    assert est.source == "estimated"
    assert est.delay_s == pytest.approx(delay_s, abs=10e-6)
    assert est.se_s < 50e-6


def test_no_delay_is_not_given_a_noisy_one():
    est = estimate_session_timing(_trials(0.0, noise_N=0.03, seed=4))
    assert est.delay_s == 0.0 and "not significant" in est.source


def test_fixed_timings():
    assert fixed_delay_s(IdentificationSettings(input_timing="hold"), 2000.0) == 0.00025
    assert fixed_delay_s(IdentificationSettings(input_timing="smooth"), 2000.0) == 0.0
    assert fixed_timing(IdentificationSettings(input_timing=-2e-4), 2000.0).delay_s == -2e-4
    assert fixed_timing(IdentificationSettings(), 2000.0) is None    # estimate
    with pytest.raises(SettingError, match="input_timing"):
        IdentificationSettings(input_timing="sometimes")
    with pytest.raises(SettingError, match="input_timing"):
        IdentificationSettings(input_timing=0.5)


def test_pooling_weights_and_clips():
    assert pooled([(5e-3, 1e-6)], 1e-3).delay_s == 1e-3
    assert "bound" in pooled([(5e-3, 1e-6)], 1e-3).source
    assert pooled([(2e-4, 1e-5), (1e-3, 1e-3)], 1e-3).delay_s == pytest.approx(2.0e-4, rel=0.01)


def _simulated_level(sE=0.8):
    """Three repeats of one level from the simulated rig (its stimulator holds samples)."""
    from nmsid.sim_backends import make_population
    from nmsid.sim_backends.simulation import ParticipantSimulator
    participant = make_population(1, seed=2026)[0]
    sim = ParticipantSimulator(participant, FS)
    cal = participant.calibration
    t = np.arange(int((STEADY_S + CHIRP_S) * FS)) / FS
    rE = _chirp(t)
    trials = []
    for r in (1, 2, 3):
        I_e = cal.Iemin_mA + rE * sE * (cal.Iemax_mA - cal.Iemin_mA)
        I_f = cal.Ifmin_mA + (1 - rE) * sE * (cal.Ifmax_mA - cal.Ifmin_mA)
        force = sim.simulate(I_e, I_f).force_N
        trials.append(Trial(sE=sE, repeat=r, fs_Hz=FS, rE=rE, I_ext_mA=I_e, I_flex_mA=I_f,
                            force_N=force, steady_s=STEADY_S, chirp_s=CHIRP_S))
        sim.advance_quiet(int(20 * FS))
    return trials


def test_clean_simulated_session_passes_the_residual_tests():
    """The demo's complaint: a clean simulated level flagged ``resid-input corr`` because
    identification took the held samples for a smooth input. With the timing estimated it
    passes; assuming a smooth input (the old belief) the flag comes back."""
    trials = _simulated_level()
    ok = identify_level(trials)
    assert ok.fit is not None and ok.fit.residual_tests.independence_pass, ok.problems
    assert ok.data.input_delay_s == pytest.approx(0.25e-3, abs=20e-6)
    old = identify_level(trials, IdentificationSettings(input_timing="smooth"))
    assert not old.fit.residual_tests.independence_pass
