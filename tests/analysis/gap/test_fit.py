"""The joint output-error fit recovers known parameters; the fatigue law is the same for
training and held-out trials."""

import numpy as np
import pytest

from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.fit import fit_model, predict
from nmsid.analysis.gap.models import NOMINAL, candidate
from nmsid.protocols.effects import Effect


def test_nominal_fit_recovers_parameters(nominal_session, true_params):
    data = load_session(nominal_session)
    fit = fit_model(data, NOMINAL)
    for j, sE in enumerate(data.sE_levels):
        Kp, wn, zeta = true_params(sE)
        assert fit.Kp[j] == pytest.approx(Kp, rel=0.01)
        assert fit.wn_rad_s[j] == pytest.approx(wn, rel=0.01)
        assert fit.zeta[j] == pytest.approx(zeta, rel=0.01)


def test_dead_time_fit_recovers_delay(dead_time_session):
    data = load_session(dead_time_session)
    nom = fit_model(data, NOMINAL)
    fit = fit_model(data, candidate(Effect.DEAD_TIME), start=nom)
    assert fit.params["L_s"] == pytest.approx(0.030, rel=0.05)
    assert fit.rss < 0.01 * nom.rss


def test_fatigue_gain_is_anchored_at_session_start(nominal_session):
    data = load_session(nominal_session)
    cand = candidate(Effect.FATIGUE)
    p = np.array([1.0])  # 1e-3 per s
    full = cand.gain(data, p)
    part = cand.gain(data.subset([3, 7]), p)
    np.testing.assert_allclose(part, full[[3, 7]])


def test_predict_uses_only_the_trials_given(nominal_session):
    data = load_session(nominal_session)
    fit = fit_model(data.subset(np.flatnonzero(data.repeat != 1)), NOMINAL)
    r, pred, ref = predict(fit, data.subset(np.flatnonzero(data.repeat == 1)))
    assert r.shape == ref.shape == (5, data.y_N.shape[1])
    assert 100 * np.sqrt(np.sum(r ** 2) / np.sum(ref ** 2)) < 2.0


def test_recruitment_basis_equals_the_spline_and_filter_it_replaces(nominal_session):
    from nmsid.analysis.gap.models import (
        RECRUITMENT_KNOTS,
        RecruitmentBasis,
        recruitment_curve,
        recruitment_excess,
    )
    data = load_session(nominal_session)
    basis = RecruitmentBasis(data)
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(-4, 4, len(RECRUITMENT_KNOTS) - 2)
        want = recruitment_excess(data, recruitment_curve(q))
        np.testing.assert_allclose(basis.excess(q), want, atol=1e-12 * np.abs(want).max())
