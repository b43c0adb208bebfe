"""Fitting the physiological twin (analysis.muscle.fit) and its place in the gap diagnosis."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.analysis.gap.diagnose import GapSettings, diagnose
from nmsid.analysis.muscle.dynamics import PARAM_NAMES
from nmsid.analysis.muscle.errors import MuscleFitError
from nmsid.analysis.muscle.fit import MuscleFitSettings, fit_muscle
from nmsid.protocols.effects import Effect

from .conftest import TRUE


def test_own_equations_are_recovered_with_their_uncertainty(twin_data):
    """Data from the twin's own equations at 1 kHz through the identification's filters.

    The fit's model filters at the fit rate only (the Savitzky-Golay stage of the raw rate
    is not reproduced), a small lead/lag that tau_act and the sensor's zero share: those
    two carry a bias the statistical uncertainty does not cover (docs/muscle-twin.md)."""
    fit = fit_muscle(twin_data, MuscleFitSettings(max_iter=40))
    assert fit.nrmse_pct < 1.0
    rows = {r["name"]: r for r in fit.table()}
    tol = {"wn0_rad_s": 0.02, "zeta0": 0.02, "F_e_N": 0.03, "F_f_N": 0.03,
           "tau_deact_s": 0.05, "k_e": 0.1, "k_f": 0.3, "c_s_per_s": 0.05, "w_e": 0.03, "w_f": 0.03,
           "tau_act_s": 0.2}
    for name, t in tol.items():
        k = PARAM_NAMES.index(name)
        err = abs(fit.theta[k] / TRUE[name] - 1)
        assert err < t, (name, fit.theta[k], TRUE[name])
        assert rows[name]["determined"] is True
    for name in ("wn0_rad_s", "zeta0"):   # the uncertainty covers the error where unbiased
        k = PARAM_NAMES.index(name)
        err = abs(fit.theta[k] / TRUE[name] - 1)
        assert err < 5 * rows[name]["sd_rel_pct"] / 100 + 0.002, (name, err, rows[name])
    assert len(fit.singular_values) == len(PARAM_NAMES)
    assert fit.singular_values[0] >= fit.singular_values[-1] > 0


def test_a_fit_rate_off_the_grid_is_refused_in_one_line(twin_data):
    with pytest.raises(MuscleFitError, match="fs_fit_Hz = 70"):
        fit_muscle(twin_data, MuscleFitSettings(fs_fit_Hz=70.0))


def test_independent_formulation_is_scored_and_reported(hill_data):
    """Compliant-tendon Hill muscles (not the twin's equations, not MuJoCo's): the muscle
    twin is tried beside the library's candidates and the verdict keeps a remainder when
    one is left."""
    s = GapSettings(candidates=(Effect.ACTIVATION_DYNAMICS,), try_pairs=False)
    diag = diagnose(hill_data, s)
    m = diag.muscle_tried
    assert m is not None
    assert m.heldout_nrmse_pct < 0.5 * diag.nominal.heldout_nrmse_pct
    # one parameter set against 3 per sE level and the timing: 18 - (3 x 5 + 1)
    assert np.isfinite(m.delta_ic) and m.delta_k == len(PARAM_NAMES) - (3 * 5 + 1)
    v = diag.assessment
    if m.supported:
        assert v["verdict"] == "muscle_twin"
    else:
        assert v["verdict"] in ("effect", "unexplained")
    assert "remaining" in v and v["remaining"]["n_trials"] == int(diag.tested.sum())
    # the report says how much the muscle twin leaves and where most of it lies
    from nmsid.analysis.muscle.report import muscle_section
    rem = muscle_section(diag)["remainder"]
    assert abs(rem["to_noise_floor"] * diag.noise_floor_nrmse_pct - m.heldout_nrmse_pct) \
        < 1e-9
    assert rem["worst_sE"]["sE"] in diag.data.sE_levels and rem["worst_band"] is not None
    assert f"{m.heldout_nrmse_pct:.2f} % held-out" in rem["sentence"]


def test_model_filter_is_the_measured_force_chain(twin_data):
    """The model's force passes the measured force's chain (Savitzky-Golay and low-pass
    at the raw rate) by its frequency response: a sinusoid through both agrees."""
    from nmsid.analysis.muscle.fit import _Problem, chain_response
    from nmsid.analysis.preprocess import smooth_and_lowpass
    sig = twin_data.settings.signal
    fs = twin_data.fs_raw_Hz
    t = np.arange(int(20 * fs)) / fs
    for f in (2.0, 8.0, 15.0):
        x = np.sin(2 * np.pi * f * t)
        y = smooth_and_lowpass(x, fs, sig)[5000:-5000]
        gain = np.sum(y * x[5000:-5000]) / np.sum(x[5000:-5000] ** 2)
        assert abs(chain_response(np.array([f]), fs, sig)[0].real - gain) < 2e-4
    prob = _Problem(twin_data, MuscleFitSettings())
    tt = np.arange(prob.rE.shape[1]) * prob.dt_s
    x = np.sin(2 * np.pi * 8.0 * tt)[None, None]
    y = prob.filter(x, np.array([0.0]))[0, 0]
    H = chain_response(np.array([8.0]), fs, sig)[0].real
    mid = slice(200, -200)
    assert np.max(np.abs(y[mid] - H * x[0, 0][mid])) < 1e-3
    y_d = prob.filter(x, np.array([0.02]))[0, 0]        # a delay of two fit steps
    assert np.max(np.abs(y_d[mid] - H * np.sin(2 * np.pi * 8.0 * (tt - 0.02))[mid])) < 1e-3


def test_subset_refit_matches_a_full_refit_and_never_raises_its_own_cost(twin_data):
    """Each fold's twin (one damped Gauss-Newton step from the fit on every trial, chosen
    on the fold's own trials) predicts the left-out trials as a full refit does."""
    from nmsid.analysis.muscle.fit import residual_matrix, subset_refit
    full = fit_muscle(twin_data, MuscleFitSettings(max_iter=40))
    keep = np.flatnonzero(twin_data.repeat == 1)
    out = np.flatnonzero(twin_data.repeat != 1)
    thetas, R = subset_refit(full, twin_data, [keep])
    refit = fit_muscle(twin_data.subset(keep), MuscleFitSettings(max_iter=40),
                       start=full.theta)
    R_refit = residual_matrix(refit.theta, twin_data)[0]
    R_full = residual_matrix(full.theta, twin_data)[0]
    held = np.sqrt(np.mean(R[0][out] ** 2))
    assert held <= 1.1 * np.sqrt(np.mean(R_refit[out] ** 2)) + 1e-4
    assert np.sum(R[0][keep] ** 2) <= np.sum(R_full[keep] ** 2) * (1 + 1e-9)
    assert thetas.shape == (1, len(PARAM_NAMES))


def test_sos_response_is_sosfreqz():
    """The chain's low-pass response without scipy.signal equals scipy's to rounding."""
    import scipy.signal as ss

    from nmsid.analysis.muscle.fit import sos_response
    f = np.linspace(0.0, 60.0, 301)
    for order, fc, fs in ((2, 25.0, 2000.0), (4, 25.0, 200.0), (3, 10.0, 100.0)):
        sos = ss.butter(order, fc, fs=fs, output="sos")
        _, want = ss.sosfreqz(sos, worN=f, fs=fs)
        np.testing.assert_allclose(sos_response(sos, f, fs), want, rtol=1e-12, atol=1e-14)


def test_a_fatiguing_session_is_fitted_with_its_trial_gains(twin_data):
    """Issue 40: with fatigue the muscle twin fell to 'not supported'. The same data with
    each trial's force scaled by a falling gain (25 % over the session, in trial order):
    given the gains, one parameter set fits as well as the unfatigued data; without them
    it cannot."""
    import dataclasses
    n = twin_data.n_trials
    g = 1.0 - 0.25 * np.arange(n) / (n - 1)
    g = g / g.mean()
    tired = dataclasses.replace(twin_data, y_N=twin_data.y_N * g[:, None])
    base = fit_muscle(twin_data, MuscleFitSettings(max_iter=20))
    with_g = fit_muscle(tired, MuscleFitSettings(max_iter=20, trial_gain=tuple(g)))
    without = fit_muscle(tired, MuscleFitSettings(max_iter=20))
    assert with_g.nrmse_pct < 2.5 * base.nrmse_pct      # 20 iterations from the same start
    assert without.nrmse_pct > 3 * with_g.nrmse_pct
