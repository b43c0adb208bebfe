"""Validation sessions: physiological scatter per trial on both kinds of participant,
common random numbers between protocols."""

import numpy as np
import pytest

from nmsid.analysis.design.candidates import Candidate
from nmsid.analysis.design.validate import simulate_session

SHORT = Candidate(sE_levels=(0.5, 0.9), repeats=2, steady_s=1.0, chirp_s=3.0, rest_s=10.0)


def _swing(trial):
    """Peak-to-peak of the force over the excitation, in N."""
    f = trial.force_N[int(trial.steady_s * trial.fs_Hz) + 200:]
    return float(np.percentile(f, 99) - np.percentile(f, 1))


def _participants():
    from nmsid.sim_backends.population import make_population
    out = [make_population(1, seed=4)[0]]
    try:
        from nmsid.sim_backends.msk_population import make_msk_population
    except ImportError:
        return out
    return out + [make_msk_population(1, seed=7)[0]]


@pytest.mark.parametrize("vp", _participants(), ids=lambda vp: type(vp).__name__)
def test_gain_scatter_changes_each_repeat_and_is_reproducible(vp):
    plain = simulate_session(vp, SHORT, seed=3)
    varied = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3)
    again = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3)
    for a, b in zip(varied.trials, again.trials):
        np.testing.assert_array_equal(a.force_N, b.force_N)
    ratios = np.array([_swing(v) / _swing(p) for v, p in zip(varied.trials, plain.trials)])
    # without scatter the swing is the same within sensor noise; with 15 % gain scatter
    # the four trials (independent draws) move by several percent, not all the same way
    assert np.max(np.abs(ratios - 1)) > 0.03, ratios
    assert np.ptp(ratios) > 0.03, ratios


def test_two_protocols_share_the_draw_of_a_level_and_repeat():
    """Common random numbers: the same (sE, repeat) gets the same physiology whatever the
    protocol, so a longer lead-in changes the trial's start, not its participant."""
    from nmsid.sim_backends.population import make_population
    vp = make_population(1, seed=4)[0]
    longer = Candidate(sE_levels=(0.5, 0.9), repeats=2, steady_s=1.0, chirp_s=3.0,
                       rest_s=30.0)
    a = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3)
    b = simulate_session(vp, longer, scatter={"Kp": 0.15}, seed=3)
    for x, y in zip(a.trials, b.trials):
        np.testing.assert_array_equal(x.force_N, y.force_N)
