"""Predicted standard errors: closed forms, scaling laws, delta method and the AICc choice."""

import dataclasses

import numpy as np
import pytest

from nmsid.analysis.curves import fit_curve
from nmsid.analysis.design.candidates import PAPER_LEVELS, Candidate, paper_candidate
from nmsid.analysis.design.predict import Predictor, curve_gradient, derived_quantities, sd_ratio
from nmsid.analysis.design.prior import Prior, PriorCurve, PriorParticipant


def _prior(kp=("linear", (1.0, 8.0)), wn=("quadratic", (5.0, 60.0, -40.0)),
           zeta=("exponential", (0.3, 0.9)), noise=0.04, code="T1"):
    curves = {"Kp": PriorCurve(*kp), "wn_rad_s": PriorCurve(*wn),
              "zeta": PriorCurve(*zeta)}
    return Prior((PriorParticipant(code, curves, noise),), "test")


SHORT = Candidate(steady_s=1.0, chirp_s=4.0, repeats=1, rest_s=10.0,
                  sE_levels=(0.3, 0.45, 0.6, 0.75, 0.9, 1.0))


@pytest.mark.parametrize("scatter", [{"Kp": 0.0, "wn_rad_s": 0.0, "zeta": 0.0},
                                     {"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.02}])
def test_linear_curve_se_matches_the_weighted_least_squares_closed_form(scatter):
    pr = Predictor(_prior(), scatter=scatter)
    pred = pr.predict(SHORT)
    x = np.asarray(SHORT.sE_levels)
    w = 1 / pred.level_se[0, :, 0] ** 2             # Kp is linear in this prior
    xb = np.sum(w * x) / np.sum(w)
    grid = np.asarray(PAPER_LEVELS)
    closed = np.sqrt(1 / np.sum(w) + (grid - xb) ** 2 / np.sum(w * (x - xb) ** 2))
    assert np.allclose(pred.curve_se[0, :, 0], closed, rtol=1e-9)


def test_repeats_and_amplitude_scale_as_the_bound_says():
    no_scatter = {"Kp": 0.0, "wn_rad_s": 0.0, "zeta": 0.0}
    for scatter in (no_scatter, {"Kp": 0.2, "wn_rad_s": 0.1, "zeta": 0.1}):
        pr = Predictor(_prior(), scatter=scatter)
        one = pr.predict(SHORT)
        three = pr.predict(dataclasses.replace(SHORT, repeats=3))
        assert np.allclose(one.level_se / three.level_se, np.sqrt(3), rtol=1e-9)
        assert sd_ratio(one, three).max == pytest.approx(np.sqrt(3), rel=1e-9)
    pr = Predictor(_prior(), scatter=no_scatter)
    half = pr.predict(dataclasses.replace(SHORT, rE_amplitude=0.25))
    assert np.allclose(half.level_se / pr.predict(SHORT).level_se, 2.0, rtol=1e-9)


def test_scatter_dominated_levels_hardly_depend_on_excitation_length():
    scatter = {"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.05}
    pr = Predictor(_prior(), scatter=scatter)
    short = pr.predict(dataclasses.replace(SHORT, chirp_s=4.0, repeats=3))
    long = pr.predict(dataclasses.replace(SHORT, chirp_s=12.0, repeats=3))
    r = short.level_se / long.level_se
    assert np.all(r >= 1.0) and np.all(r < 1.01)
    # ... whereas with sensor noise only, seconds trade one to one with variance
    pr0 = Predictor(_prior(), scatter={"Kp": 0, "wn_rad_s": 0, "zeta": 0})
    r0 = pr0.predict(dataclasses.replace(SHORT, chirp_s=4.0)).level_se / \
        pr0.predict(dataclasses.replace(SHORT, chirp_s=12.0)).level_se
    assert np.all((r0 > 1.5) & (r0 < 2.0))


@pytest.mark.parametrize("coeffs", [(5.0, 60.0, -40.0), (40.0, -30.0, 25.0)])
def test_extremum_standard_error_matches_monte_carlo_refits(coeffs):
    x = np.linspace(0.3, 1.0, 8)
    sd = np.full(len(x), 0.3)
    G = curve_gradient("quadratic", coeffs, x)
    cov = np.linalg.inv(G.T @ (G / sd[:, None] ** 2))
    pred = derived_quantities("quadratic", coeffs, cov)
    rng = np.random.default_rng(3)
    truth = np.polyval(coeffs[::-1], x)
    xs = []
    for _ in range(3000):
        c = fit_curve("quadratic", x, truth + sd * rng.standard_normal(len(x))).coefficients
        xs.append(-c[1] / (2 * c[2]))
    assert pred.extremum_sE is not None and pred.rate is None and pred.slope is None
    assert np.std(xs) == pytest.approx(pred.extremum_sE[1], rel=0.1)
    assert pred.extremum_sE[0] == pytest.approx(-coeffs[1] / (2 * coeffs[2]))
    assert list(pred.to_dict()) == ["extremum_sE", "extremum_value"]


def test_exponential_rate_se_is_the_coefficient_se():
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])
    got = derived_quantities("exponential", (1.0, 2.0), cov)
    assert got.rate == (2.0, 0.3) and got.to_dict() == {"rate": (2.0, 0.3)}


def test_selection_accuracy_high_when_precise_low_when_noisy():
    prior = _prior(kp=("exponential", (0.5, 3.0)), wn=("quadratic", (5.0, 80.0, -55.0)),
                   zeta=("linear", (0.3, 0.4)))
    precise = Predictor(prior, scatter={"Kp": 0.0, "wn_rad_s": 0.0, "zeta": 0.0})
    acc = precise.selection_accuracy(precise.predict(paper_candidate()), draws=40)
    assert acc.per_parameter["Kp"] >= 0.95 and acc.per_parameter["wn_rad_s"] >= 0.95
    assert acc.to_dict()["overall"] == acc.overall and acc.draws_per_participant == 40
    noisy = Predictor(prior, scatter={"Kp": 0.5, "wn_rad_s": 0.5, "zeta": 0.5})
    acc_n = noisy.selection_accuracy(noisy.predict(SHORT), draws=40)
    assert acc_n.overall < acc.overall - 0.15


def test_population_prior_predicts_for_every_participant():
    from nmsid.analysis.design.prior import population_prior
    pr = Predictor(population_prior(3, seed=5))
    pred = pr.predict(SHORT)
    assert pred.curve_se.shape == (3, 15, 3) and np.all(np.isfinite(pred.curve_se))
    assert np.all(pred.curve_se > 0)


def _write_params(path, x, values, ses, n_trials=3, code="T1"):
    lines = ["participant,sE,Kp,wn_rad_s,zeta,n_trials,Kp_se,wn_se,zeta_se"]
    for i, s in enumerate(x):
        lines.append(",".join([code, f"{s:.6f}"] + [f"{v:.9g}" for v in values[i]]
                              + [str(n_trials)] + [f"{v:.9g}" for v in ses[i]]))
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("s_trial", [(0.1, 0.05, 0.02), (0.03, 0.2, 0.08)])
def test_scatter_measured_on_a_first_session_recovers_the_per_trial_scatter(tmp_path, s_trial):
    from nmsid.analysis.design.prior import scatter_from_parameters
    prior = _prior()
    who = prior.participants[0]
    x = np.linspace(0.3, 1.0, 400)
    rng = np.random.default_rng(4)
    truth = np.column_stack([who.curves[n](x) for n in ("Kp", "wn_rad_s", "zeta")])
    level_sd = np.array(s_trial) / np.sqrt(3)          # 3 trials averaged per level
    ses = 0.002 * truth                                  # the fit's own SE: small, removed
    values = truth * (1 + level_sd * rng.standard_normal(truth.shape)) \
        + ses * rng.standard_normal(truth.shape)
    _write_params(tmp_path / "p.csv", x, values, ses)
    got = scatter_from_parameters(tmp_path / "p.csv", prior)
    for name, want in zip(("Kp", "wn_rad_s", "zeta"), s_trial, strict=True):
        assert getattr(got, name) == pytest.approx(want, rel=0.12)


def test_scatter_is_zero_when_the_standard_errors_explain_the_residuals(tmp_path):
    from nmsid.analysis.design.prior import scatter_from_parameters
    prior = _prior()
    who = prior.participants[0]
    x = np.linspace(0.3, 1.0, 300)
    truth = np.column_stack([who.curves[n](x) for n in ("Kp", "wn_rad_s", "zeta")])
    ses = 0.01 * truth
    values = truth + ses * np.random.default_rng(1).standard_normal(truth.shape)
    _write_params(tmp_path / "p.csv", x, values, ses)
    got = scatter_from_parameters(tmp_path / "p.csv", prior)
    assert all(v < 0.01 for v in got.to_dict().values())


def test_scatter_from_a_bad_file_names_it(tmp_path):
    from nmsid.analysis.design.errors import DesignError
    from nmsid.analysis.design.prior import scatter_from_parameters
    with pytest.raises(DesignError, match="nope.csv"):
        scatter_from_parameters(tmp_path / "nope.csv", _prior())
    (tmp_path / "few.csv").write_text("participant,sE,Kp,wn_rad_s,zeta,n_trials,Kp_se,"
                                      "wn_se,zeta_se\nT1,0.3,1,2,3,3,0,0,0\n")
    with pytest.raises(DesignError, match="at least"):
        scatter_from_parameters(tmp_path / "few.csv", _prior())
