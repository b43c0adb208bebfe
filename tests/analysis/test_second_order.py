"""The output-error fitter on closed-form cases, and its failure modes."""

import math

import numpy as np
import pytest

from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.second_order import _Problem, fit_second_order
from nmsid.analysis.settings import IdentificationSettings

LINEAR = IdentificationSettings(input_hold="linear", estimate_trend=False)


def poles(wn, zeta):
    d = np.sqrt(complex(zeta * zeta - 1))
    return -zeta * wn + wn * d, -zeta * wn - wn * d


def ramp_response(t, Kp, wn, zeta):
    """Closed-form response of Kp wn^2/(s^2+2 zeta wn s+wn^2) to the unit ramp t (t >= 0):
    partial fractions of wn^2 / (s^2 (s - p1)(s - p2))."""
    p1, p2 = poles(wn, zeta)
    t = np.asarray(t, dtype=float)
    tp = np.clip(t, 0, None)
    r = tp - 2 * zeta / wn + (wn ** 2 * np.exp(p1 * tp) / (p1 ** 2 * (p1 - p2))
                             + wn ** 2 * np.exp(p2 * tp) / (p2 ** 2 * (p2 - p1))).real
    return Kp * np.where(t > 0, r, 0.0)


@pytest.mark.parametrize("Kp,wn,zeta", [(5.0, 20.0, 0.3), (12.0, 55.0, 0.9), (3.0, 10.0, 0.5)])
def test_step_closed_form(Kp, wn, zeta):
    fs = 1000.0
    t = np.arange(3000) / fs
    k0 = 500                                   # the step reaches 1 at sample k0
    u = (np.arange(3000) >= k0).astype(float)
    h = 1 / fs
    # piecewise-linear input: ramp from t[k0-1] to t[k0]
    y = (ramp_response(t - t[k0 - 1], Kp, wn, zeta) - ramp_response(t - t[k0], Kp, wn, zeta)) / h
    from scipy.signal import lsim  # the closed form is right
    assert np.max(np.abs(y - lsim(([Kp * wn * wn], [1, 2 * zeta * wn, wn * wn]), u, t)[1])) \
        < 1e-9 * Kp
    f = fit_second_order(u - u.mean(), y + 0.7, fs, LINEAR)
    assert f.converged
    assert (f.Kp, f.wn_rad_s, f.zeta) == pytest.approx((Kp, wn, zeta), rel=1e-6)
    assert f.offset_N == pytest.approx(0.7 + Kp * u.mean(), rel=1e-6)


def test_impulse_closed_form():
    Kp, wn, zeta, fs = 4.0, 35.0, 0.25, 2000.0
    n, k0, h = 4000, 200, 1 / 2000.0
    t = np.arange(n) / fs
    u = np.zeros(n)
    u[k0] = 1 / h                              # a triangle pulse of unit area
    y = (ramp_response(t - t[k0 - 1], Kp, wn, zeta) - 2 * ramp_response(t - t[k0], Kp, wn, zeta)
         + ramp_response(t - t[k0 + 1], Kp, wn, zeta)) / h ** 2
    f = fit_second_order(u - u.mean(), y, fs, LINEAR)
    assert (f.Kp, f.wn_rad_s, f.zeta) == pytest.approx((Kp, wn, zeta), rel=1e-6)


@pytest.mark.parametrize("fs", [1000.0, 2000.0])
@pytest.mark.parametrize("Kp,wn,zeta", [(7.0, 35.0, 0.45), (2.5, 9.0, 1.15), (14.0, 58.0, 0.2)])
def test_sum_of_sines_steady_state_smooth_input(fs, Kp, wn, zeta):
    """Exact steady-state response to a smooth input (any initial state is in the model)."""
    t = np.arange(int(6 * fs)) / fs
    freqs = [1.0, 2.3, 3.7, 5.1, 7.9]
    phases = [0.1, 1.0, 2.0, 0.5, 3.0]
    u = sum(0.1 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True))
    y = np.zeros_like(t)
    for f, p in zip(freqs, phases, strict=True):
        s = 2j * np.pi * f
        g = Kp * wn ** 2 / (s * s + 2 * zeta * wn * s + wn ** 2)
        y += 0.1 * abs(g) * np.sin(2 * np.pi * f * t + p + np.angle(g))
    fit = fit_second_order(u, y - 0.2 + 0.05 * t, fs)      # offset and ramp
    assert (fit.Kp, fit.wn_rad_s, fit.zeta) == pytest.approx((Kp, wn, zeta), rel=1e-6)
    assert fit.trend_N_per_s == pytest.approx(0.05, rel=1e-5)
    assert fit.fit_pct > 99.999


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    v = np.cumsum(rng.standard_normal(400)) * 0.1
    prob = _Problem(v, rng.standard_normal(400), 0.005, True)
    p = np.array([math.log(30.0), math.log(0.4)])
    ev = prob.evaluate(p, jacobian=True)
    coef = ev["coef"]
    for j in range(2):
        d = np.zeros(2)
        d[j] = 1e-6
        plus = coef @ prob.evaluate(p + d, jacobian=False)["basis"]
        minus = coef @ prob.evaluate(p - d, jacobian=False)["basis"]
        num = (plus - minus) / 2e-6
        assert np.max(np.abs(num - ev["jp"][j])) < 1e-6 * np.max(np.abs(num))



def test_jacobian_added_later_is_the_one_computed_at_once():
    """The search evaluates trial points without the Jacobian and adds it when a point is
    accepted: bit for bit the Jacobian an evaluation with ``jacobian=True`` gives."""
    rng = np.random.default_rng(7)
    v = np.cumsum(rng.standard_normal(500)) * 0.1
    prob = _Problem(v, rng.standard_normal(500), 0.005, True)
    p = np.array([math.log(25.0), math.log(0.3)])
    eager = prob.evaluate(p, jacobian=True)
    lazy = prob.evaluate(p, jacobian=False)
    assert "jp" not in lazy and "j_reduced" not in lazy
    assert prob.jacobian(lazy) is lazy
    for key in ("jp", "j_reduced", "resid", "coef"):
        assert np.array_equal(lazy[key], eager[key])


def test_residual_tests_run_on_first_use_with_the_fit_s_residual():
    from nmsid.analysis.residual_tests import residual_tests
    rng = np.random.default_rng(8)
    t = np.arange(0, 6, 0.005)
    u = np.sin(2 * np.pi * (0.5 + 0.8 * t) * t)
    from scipy.signal import lsim
    y = lsim(([2.0 * 225.0], [1, 2 * 0.4 * 15.0, 225.0]), u, t)[1] \
        + 0.3 * rng.standard_normal(len(t))
    s = IdentificationSettings()
    fit = fit_second_order(u, y, 200.0, s)
    assert fit._tests is None                     # not run by the fit itself
    got = fit.residual_tests
    want = residual_tests(fit.residual_N, u, s.resid_lags, s.resid_confidence)
    assert fit.residual_tests is got              # run once
    assert np.array_equal(got.autocorrelation, want.autocorrelation)
    assert np.array_equal(got.cross_correlation, want.cross_correlation)
    assert (got.whiteness_pass, got.independence_pass) == \
        (want.whiteness_pass, want.independence_pass)
    u[:] = 0.0                                    # the caller's array is not the fit's
    assert np.array_equal(fit.residual_tests.cross_correlation, want.cross_correlation)


def test_standard_errors_track_the_noise():
    fs = 200.0
    t = np.arange(2000) / fs
    u = 0.5 * np.sin(2 * np.pi * (1 + 0.45 * t) * t)
    from scipy.signal import lsim
    y0 = lsim(([5 * 900.0], [1, 2 * 0.4 * 30, 900.0]), u, t)[1]
    rng = np.random.default_rng(5)
    fits = [fit_second_order(u, y0 + rng.normal(0, 0.05, len(t)), fs) for _ in range(2)]
    for f in fits:
        assert f.noise_sd_N == pytest.approx(0.05, rel=0.25)
        assert abs(f.Kp - 5.0) < 5 * f.Kp_se + 0.01
        assert f.residual_tests.whiteness_pass in (True, False)
    assert fits[0].Kp_se == pytest.approx(fits[1].Kp_se, rel=0.3)


def test_bad_inputs_raise_clear_errors():
    u = np.zeros(100)
    with pytest.raises(IdentificationError, match="NaN"):
        fit_second_order(u, np.full(100, np.nan), 200.0)
    with pytest.raises(IdentificationError, match="at least"):
        fit_second_order(u[:10], u[:10], 200.0)
    with pytest.raises(IdentificationError, match="equal length"):
        fit_second_order(u, u[:50], 200.0)


def test_non_converging_fit_is_flagged_not_raised():
    t = np.arange(1000) / 200.0
    u = np.sin(2 * np.pi * 3 * t)
    y = np.random.default_rng(0).standard_normal(1000)        # no relation to u
    f = fit_second_order(u, y, 200.0, IdentificationSettings(max_iterations=1))
    assert f.converged is False and f.message == "iteration limit reached"
    assert f.fit_pct < 50
    assert not math.isnan(f.Kp)


def test_residual_tests_detect_unmodelled_dynamics():
    from nmsid.analysis.residual_tests import residual_tests
    rng = np.random.default_rng(2)
    u = rng.standard_normal(3000)
    e = np.convolve(u, [0, 0.5, 0.3], mode="same") * 0.5 + rng.standard_normal(3000)
    r = residual_tests(e, u)
    assert not r.independence_pass
    ok = residual_tests(rng.standard_normal(3000), u)
    assert ok.whiteness_pass and ok.independence_pass
    assert "whiteness pass" in ok.summary()


@pytest.mark.parametrize("start", [(300.0, 0.02), (5.0, 2.0), (1000.0, 0.01)])
def test_far_starts_converge_to_the_truth(start):
    """Variable projection leaves only (wn, zeta) to search: far starts still converge."""
    fs = 200.0
    t = np.arange(2000) / fs
    u = 0.5 * np.sin(2 * np.pi * (1 + 0.45 * t) * t)
    from scipy.signal import lsim
    y = lsim(([5 * 900.0], [1, 2 * 0.4 * 30, 900.0]), u, t)[1]     # piecewise-linear u
    f = fit_second_order(u, y, fs, LINEAR, start=start)
    assert f.converged
    assert (f.Kp, f.wn_rad_s, f.zeta) == pytest.approx((5.0, 30.0, 0.4), rel=1e-6)
