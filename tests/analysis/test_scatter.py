"""Trial-to-trial scatter (analysis.scatter): the pooled log-SD and its chi-square interval
in closed form, and the scatter of an independent generator recovered by identify."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from nmsid.analysis.fatigue import fit_fatigue
from nmsid.analysis.identify import identify_session
from nmsid.analysis.scatter import ScatterResult, TrialFit, summarise

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from trial_sessions import TrialPhysiology, write_session


def _fits(values: dict[float, list[tuple[float, float, float]]], se=0.0, cum=None):
    out = []
    for sE, rows in values.items():
        for k, (kp, wn, z) in enumerate(rows):
            out.append(TrialFit(f"t{sE}{k}", sE, k + 1, kp, wn, z, se * kp, se * wn, se * z,
                                99.0, float(cum[(sE, k)]) if cum else float("nan")))
    return out


def test_pooled_log_sd_and_chi_square_interval_in_closed_form():
    vals = {0.3: [(2.0, 20.0, 0.5), (2.2, 21.0, 0.5), (1.9, 19.0, 0.55)],
            0.6: [(5.0, 30.0, 0.6), (5.5, 30.0, 0.66)]}
    r = summarise(_fits(vals))
    lg = [np.log([2.0, 2.2, 1.9]), np.log([5.0, 5.5])]
    ss = sum(float(np.sum((g - g.mean()) ** 2)) for g in lg)
    s = math.sqrt(ss / 3)
    assert r.Kp.cv_pct == pytest.approx(100 * s) and r.Kp.dof == 3 and r.Kp.n_trials == 5
    assert r.Kp.ci_low_pct == pytest.approx(100 * s * math.sqrt(3 / stats.chi2.ppf(0.975, 3)))
    assert r.Kp.ci_high_pct == pytest.approx(100 * s * math.sqrt(3 / stats.chi2.ppf(0.025, 3)))
    lv = r.levels[1]
    assert lv.sE == 0.6 and lv.n_trials == 2
    assert lv.zeta.cv_pct == pytest.approx(100 * abs(math.log(0.66 / 0.6)) / math.sqrt(2))
    assert r.wn_rad_s.ci_low_pct < r.wn_rad_s.cv_pct < r.wn_rad_s.ci_high_pct
    with pytest.raises(ValueError):
        r.pooled("gain")


def test_estimation_share_is_removed_from_the_physiological_scatter():
    vals = {0.5: [(2.0, 20.0, 0.5), (2.2, 22.0, 0.55)]}
    r = summarise(_fits(vals, se=0.05))
    s = 100 * abs(math.log(1.1)) / math.sqrt(2)
    assert r.Kp.estimation_cv_pct == pytest.approx(5.0)
    assert r.Kp.physiological_cv_pct == pytest.approx(math.sqrt(s * s - 25.0))


def test_a_single_repeat_per_level_gives_no_scatter_and_says_so():
    r = summarise(_fits({0.3: [(2.0, 20.0, 0.5)], 0.6: [(3.0, 25.0, 0.5)]}))
    assert r.levels == () and r.Kp.dof == 0 and math.isnan(r.Kp.cv_pct)
    assert "not estimated" in r.sentence()


def test_significant_fatigue_is_taken_out_of_the_kp_scatter():
    lam = 4e-4
    cum = {(0.3, 0): 10.0, (0.3, 1): 300.0, (0.3, 2): 600.0, (0.6, 0): 150.0,
           (0.6, 1): 450.0, (0.6, 2): 700.0}
    vals = {sE: [(g * math.exp(-lam * cum[(sE, k)]), 20.0 + k, 0.5) for k in range(3)]
            for sE, g in ((0.3, 2.0), (0.6, 5.0))}
    fits = _fits(vals, cum=cum)
    fat = fit_fatigue([f.Kp for f in fits], [f.sE for f in fits], [f.cum_stim_s for f in fits],
                      total_stim_s=720.0)
    raw, corrected = summarise(fits), summarise(fits, fat)
    assert fat.significant and raw.Kp.cv_pct > 5
    assert corrected.fatigue_corrected and corrected.Kp.cv_pct < 1e-6
    assert corrected.wn_rad_s.cv_pct == pytest.approx(raw.wn_rad_s.cv_pct)


def test_identify_recovers_an_independent_generators_scatter(tmp_path):
    path = tmp_path / "scatter.h5"
    cv = (0.10, 0.05, 0.05)
    write_session(path, TrialPhysiology(levels=(0.3, 0.45, 0.6, 0.75, 0.9, 1.0), repeats=4,
                                        cv=cv, chirp_s=6.0), seed=11)
    res = identify_session(path)
    sc = res.scatter
    assert isinstance(sc, ScatterResult) and len(sc.levels) == 6 and sc.Kp.dof == 18
    for name, truth in zip(("Kp", "wn_rad_s", "zeta"), cv, strict=True):
        p = sc.pooled(name)
        assert p.ci_low_pct < 100 * truth < p.ci_high_pct, (name, p)
        assert p.estimation_cv_pct < 0.3 * p.cv_pct
    assert f"Kp {sc.Kp.cv_pct:.1f} %" in sc.sentence()
