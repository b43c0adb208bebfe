"""Validation by simulation: physiological scatter per trial on both kinds of participant,
independent draws per protocol stream, a scatter model other than the design's, and the
validated ratio's Monte-Carlo standard error."""

import importlib.util

import numpy as np
import pytest

from nmsid.analysis.design.api import validate_protocols
from nmsid.analysis.design.candidates import Candidate
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.predict import DEFAULT_SCATTER
from nmsid.analysis.design.prior import PARAMETERS
from nmsid.analysis.design.validate import (
    ProtocolOutcome,
    ScatterModel,
    alternative_scatter,
    simulate_session,
    validated_ratio,
)

SHORT = Candidate(sE_levels=(0.5, 0.9), repeats=2, steady_s=1.0, chirp_s=3.0, rest_s=10.0)


def _swing(trial):
    """Peak-to-peak of the force over the excitation, in N."""
    f = trial.force_N[int(trial.steady_s * trial.fs_Hz) + 200:]
    return float(np.percentile(f, 99) - np.percentile(f, 1))


def _participants():
    from nmsid.sim_backends.population import make_population
    out = [make_population(1, seed=4)[0]]
    from nmsid.sim_backends.msk_population import make_msk_population
    # the MuJoCo participant needs the optional mujoco extra to simulate (its parameters
    # are drawn without it): skipped with that reason where it is not installed
    msk = pytest.param(make_msk_population(1, seed=7)[0], marks=pytest.mark.skipif(
        importlib.util.find_spec("mujoco") is None,
        reason="the musculoskeletal participant needs the optional 'mujoco' extra"))
    return [*out, msk]


@pytest.mark.parametrize("vp", _participants(), ids=lambda vp: type(vp).__name__)
def test_gain_scatter_changes_each_repeat_and_is_reproducible(vp):
    plain = simulate_session(vp, SHORT, seed=3)
    varied = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3)
    again = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3)
    for a, b in zip(varied.trials, again.trials, strict=True):
        np.testing.assert_array_equal(a.force_N, b.force_N)
    ratios = np.array([_swing(v) / _swing(p)
                       for v, p in zip(varied.trials, plain.trials, strict=True)])
    # without scatter the swing is the same within sensor noise; with 15 % gain scatter
    # the four trials (independent draws) move by several percent, not all the same way
    assert np.max(np.abs(ratios - 1)) > 0.03, ratios
    assert np.ptp(ratios) > 0.03, ratios


def test_streams_share_or_separate_the_draw_of_a_level_and_repeat():
    """The same stream: the same (sE, repeat) gets the same physiology whatever the
    protocol (a longer rest changes nothing else); another stream draws anew."""
    from nmsid.sim_backends.population import make_population
    vp = make_population(1, seed=4)[0]
    longer = Candidate(sE_levels=(0.5, 0.9), repeats=2, steady_s=1.0, chirp_s=3.0,
                       rest_s=30.0)
    a = simulate_session(vp, SHORT, scatter={"Kp": 0.15}, seed=3, stream=1)
    b = simulate_session(vp, longer, scatter={"Kp": 0.15}, seed=3, stream=1)
    c = simulate_session(vp, longer, scatter={"Kp": 0.15}, seed=3, stream=2)
    for x, y, z in zip(a.trials, b.trials, c.trials, strict=True):
        np.testing.assert_array_equal(x.force_N, y.force_N)
        assert abs(_swing(z) / _swing(x) - 1) > 1e-3       # other gain draw, other noise


def test_scatter_models_draw_the_stated_sd_correlation_and_tails():
    rng = np.random.default_rng(0)
    sd = {"Kp": 0.10, "wn_rad_s": 0.05, "zeta": 0.05}
    normal = np.array([ScatterModel(sd).factors(rng) for _ in range(20000)]) - 1
    other = np.array([alternative_scatter(sd).factors(rng) for _ in range(20000)]) - 1
    for f in (normal, other):
        np.testing.assert_allclose(np.std(f, axis=0), [0.10, 0.05, 0.05], rtol=0.1)
    assert abs(np.corrcoef(normal.T)[0, 1]) < 0.03
    assert np.corrcoef(other.T)[0, 1] == pytest.approx(0.6, abs=0.08)
    kurt = lambda x: float(np.mean(x ** 4) / np.mean(x ** 2) ** 2)     # noqa: E731
    assert kurt(normal[:, 0]) == pytest.approx(3.0, abs=0.2)
    assert kurt(other[:, 0]) > 5.0                                     # heavy tails
    assert other.min() >= ScatterModel.MIN_FACTOR - 1


@pytest.mark.parametrize("kwargs, word", [({"correlation": 1.0}, "correlation"),
                                          ({"df": 2.0}, "df"),
                                          ({"sd": {"gain": 0.1}}, "gain")])
def test_bad_scatter_model_names_the_setting(kwargs, word):
    args = dict({"sd": {"Kp": 0.1}}, **kwargs)
    with pytest.raises(DesignError, match=word):
        ScatterModel(**args)


def _outcome(rng, sd_rel, n):
    """A protocol's curve errors: n participants, 15 levels, three parameters."""
    err = rng.standard_normal((n, 1, 3)) * sd_rel + 0.3 * sd_rel * rng.standard_normal(
        (n, 15, 3))
    return ProtocolOutcome("x", 1.0, err)


def test_the_ratio_standard_error_matches_its_monte_carlo_spread():
    """Errors of known size: the ratio is centred on the true one and its reported SE is
    the spread of the ratio over repeated experiments."""
    rng = np.random.default_rng(1)
    ratios, ses = [], []
    for _ in range(400):
        r = validated_ratio(_outcome(rng, 0.02, 20), _outcome(rng, 0.01, 20))
        ratios.append([r.per_parameter[n] for n in PARAMETERS])
        ses.append([r.se_per_parameter[n] for n in PARAMETERS])
    ratios, ses = np.array(ratios), np.array(ses)
    assert np.median(ratios) == pytest.approx(2.0, rel=0.05)
    np.testing.assert_allclose(np.std(ratios, axis=0), np.median(ses, axis=0), rtol=0.2)


def test_one_protocol_against_itself_is_one_within_its_standard_error():
    """Independent draws per protocol (the validation as ``nmsid design`` runs it): a
    protocol compared with itself is 1 within its own Monte-Carlo SE, and not exactly 1
    (as it was when both protocols saw the same draws)."""
    from nmsid.sim_backends.population import make_population
    people = make_population(6, seed=1000)
    cand = Candidate(sE_levels=(0.3, 0.5, 0.7, 0.9), repeats=2, steady_s=1.0, chirp_s=3.0,
                     rest_s=10.0, label="same")
    result = validate_protocols(people, cand, cand, DEFAULT_SCATTER, seed=0)
    v = result.to_dict()   # design.json's validation section
    assert v["validated_sd_ratio"] == result.ratio.max and v["n_participants"] == 6
    assert v["selection_accuracy"]["paper"] == result.paper.selection_accuracy().overall
    for n in PARAMETERS:
        r, se = v["validated_sd_ratio_per_parameter"][n], \
            v["validated_sd_ratio_se_per_parameter"][n]
        assert 0 < se < 1.0, (n, r, se)
        assert abs(r - 1) < 4 * se, (n, r, se)
        assert r != 1.0
    assert v["validated_sd_ratio"] == max(v["validated_sd_ratio_per_parameter"].values())
