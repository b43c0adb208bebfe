"""Curve fits, AICc and trends against hand-computed values."""

import math

import numpy as np
import pytest

from nmsid.analysis.curves import aicc, evaluate_curve, fit_curve, fit_exponential, trend_of

X = np.linspace(0.3, 1.0, 15)


def test_aicc_formula_by_hand():
    # n ln(RSS/n) + 2k + 2k(k+1)/(n-k-1)
    assert aicc(15, 2.0, 2) == pytest.approx(15 * math.log(2 / 15) + 4 + 12 / 12)
    assert aicc(15, 2.0, 3) == pytest.approx(15 * math.log(2 / 15) + 6 + 24 / 11)
    assert aicc(5, 0.5, 3) == pytest.approx(5 * math.log(0.1) + 6 + 24 / 1)
    assert aicc(4, 0.5, 3) is None          # n - k - 1 = 0
    assert aicc(3, 0.5, 2) is None


def test_polynomials_recovered_exactly():
    f = fit_curve("linear", X, 2.0 - 3.0 * X)
    assert f.coefficients == pytest.approx([2.0, -3.0], abs=1e-12)
    q = fit_curve("quadratic", X, 1.0 + 2.0 * X - 4.0 * X ** 2)
    assert q.coefficients == pytest.approx([1.0, 2.0, -4.0], abs=1e-10)
    assert q.rss < 1e-20


@pytest.mark.parametrize("a,b", [(2.0, 1.5), (-3.0, 0.8), (5.0, -2.0), (-0.5, -1.0)])
def test_exponential_any_sign(a, b):
    coef, notes = fit_exponential(X, a * np.exp(b * X))
    assert coef == pytest.approx([a, b], rel=1e-8)
    assert notes == []


def test_exponential_mixed_sign_data_is_a_least_squares_optimum():
    y = np.sin(6 * X)                       # changes sign: no log-linear start
    (a, b), _ = fit_exponential(X, y)
    cost = lambda aa, bb: float(np.sum((y - aa * np.exp(bb * X)) ** 2))  # noqa: E731
    base = cost(a, b)
    for da, db in [(1e-3, 0), (-1e-3, 0), (0, 1e-3), (0, -1e-3)]:
        assert cost(a + da * max(1, abs(a)), b + db * max(1, abs(b))) >= base


def test_exponential_rss_is_raw_scale():
    rng = np.random.default_rng(3)
    y = 2.0 * np.exp(1.2 * X) + rng.normal(0, 0.05, len(X))
    f = fit_curve("exponential", X, y)
    assert f.rss == pytest.approx(float(np.sum((y - f.predict(X)) ** 2)))
    # raw-scale LS beats the log-linear fit on raw-scale RSS
    b, loga = np.polyfit(X, np.log(y), 1)
    assert f.rss <= float(np.sum((y - np.exp(loga) * np.exp(b * X)) ** 2))


def test_too_few_points_are_not_selectable_with_reason():
    f = fit_curve("quadratic", X[:4], X[:4] ** 2)
    assert f.aicc is None and not f.selectable
    assert "n - k - 1" in f.notes[0]
    g = fit_curve("linear", X[:1], X[:1])
    assert not g.selectable and "cannot determine" in g.notes[0]


def test_noise_variance_counting_changes_k():
    y = 1 + X + np.random.default_rng(1).normal(0, 0.1, len(X))
    a = fit_curve("linear", X, y)
    b = fit_curve("linear", X, y, count_noise_variance=True)
    assert (a.k, b.k) == (2, 3)
    assert b.aicc - a.aicc == pytest.approx(2 + 2 * 3 * 4 / 11 - 2 * 2 * 3 / 12)


def test_trends_in_words():
    assert trend_of("linear", [1, 2], 0.3, 1).direction == "increasing"
    assert trend_of("exponential", [-1, 2], 0.3, 1).direction == "decreasing"
    t = trend_of("quadratic", [0.0, 2.0, -1.0], 0.3, 1.0)      # max at sE = 1
    assert t.opens == "down" and t.extremum_sE == pytest.approx(1.0)
    assert t.extremum_inside is False and t.direction == "increasing"
    assert "outside the tested range" in t.text and "maximum" in t.text
    u = trend_of("quadratic", [1.0, -1.3, 1.0], 0.3, 1.0)      # min at 0.65
    assert u.direction == "decreasing then increasing" and u.extremum_inside
    assert u.extremum_value == pytest.approx(1 - 1.3 * 0.65 + 0.65 ** 2)


def test_evaluate_curve_rejects_unknown_model():
    with pytest.raises(ValueError, match="unknown curve model"):
        evaluate_curve("cubic", [1, 2], 0.5)
