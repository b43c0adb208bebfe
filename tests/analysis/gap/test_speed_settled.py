"""``nmsid gap`` at the speed of its data (issue 30, speed item): a session whose nominal gap
is within noise skips the candidates without changing any answer; the knot slopes are
PCHIP's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import PchipInterpolator

from nmsid.analysis.gap import verdict
from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose
from nmsid.analysis.gap.models import pchip_slopes
from nmsid.protocols.effects import CANDIDATES


@pytest.fixture(scope="module")
def both(nominal_session):
    data = load_session(nominal_session)
    return diagnose(data), diagnose(data, GapSettings(skip_settled=False))


def test_settled_session_skips_the_candidates_and_says_so(both):
    fast, full = both
    assert fast.candidates == [] and fast.pairs == []
    assert fast.candidates_skipped and "within noise" in fast.candidates_skipped
    assert full.candidates_skipped is None and len(full.candidates) == len(CANDIDATES)


def test_skipping_changes_no_answer(both):
    """What the candidates would have given: the same verdict, gap, twin and held-out
    score (the point of ``nominal_settles``)."""
    fast, full = both
    for key in ("verdict", "label", "remaining", "nominal_gap"):
        assert fast.assessment[key] == full.assessment[key], key
    assert fast.best_effect == full.best_effect
    assert fast.nominal.heldout_nrmse_pct == full.nominal.heldout_nrmse_pct
    np.testing.assert_array_equal(fast.full_fit.Kp, full.full_fit.Kp)
    np.testing.assert_array_equal(fast.full_fit.wn_rad_s, full.full_fit.wn_rad_s)


@pytest.mark.parametrize("flag", ["significant", "narrow_band_significant",
                                  "concentrated_in"])
def test_any_sign_of_a_gap_keeps_the_candidates(monkeypatch, flag):
    quiet = {"significant": False, "narrow_band_significant": False, "concentrated_in": []}
    monkeypatch.setattr(verdict, "_held_out_tests",
                        lambda diag, r: ({**quiet}, []))
    diag = type("D", (), {"nominal": type("N", (), {"heldout_resid": None})()})()
    assert verdict.nominal_settles(diag)[0] is True
    loud = {**quiet, flag: ["t001"] if flag == "concentrated_in" else True}
    monkeypatch.setattr(verdict, "_held_out_tests", lambda diag, r: (loud, []))
    assert verdict.nominal_settles(diag)[0] is False


def test_knot_slopes_are_pchips():
    rng = np.random.default_rng(5)
    for i in range(300):
        x = np.unique(np.r_[0.0, rng.uniform(0, 1, rng.integers(1, 7)), 1.0])
        y = rng.normal(size=len(x)) if i % 2 else np.sort(rng.uniform(0, 1, len(x)))
        if i % 5 == 0 and len(x) > 3:
            y[2] = y[1]                               # a flat segment: zero slopes
        np.testing.assert_allclose(pchip_slopes(x, y), PchipInterpolator(x, y)(x, 1),
                                   rtol=1e-12, atol=1e-12)


def test_report_says_why_there_is_no_ranking(nominal_session, tmp_path, monkeypatch):
    """The report names the reason, and draws no empty ranking (the figure functions are
    recorded, not run: matplotlib is not what is tested)."""
    import json

    from nmsid.analysis.gap import report
    from nmsid.analysis.gap.api import run_gap
    drawn = []

    class Recorder:
        def __getattr__(self, name):
            return lambda *args, **kwargs: drawn.append(name)

    monkeypatch.setattr(report, "plots", Recorder())
    run_gap([nominal_session], tmp_path, plots=True)
    rep = json.loads((tmp_path / "gap_report.json").read_text(encoding="utf-8"))
    assert rep["ranking"] == [] and "within noise" in rep["candidates_not_fitted"]
    assert rep["evidence"]["summary"][0].startswith("none: no candidate fitted")
    assert "--all-candidates" in (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "plot_where" in drawn and "plot_ranking" not in drawn
    assert "ranking.png" not in rep["figures"]


def _all_candidates():
    from nmsid.analysis.gap.models import candidate
    singles = [candidate(e) for e in CANDIDATES]
    pairs = [candidate(a, b) for i, a in enumerate(CANDIDATES) for b in CANDIDATES[i + 1:]]
    return singles + pairs


def _at(cand, share):
    """Every entry of ``p`` at ``share`` of its bounds."""
    lo, hi = cand.bounds()
    return np.where(np.isfinite(lo) & np.isfinite(hi), lo + share * (hi - lo), share)


def _moved(cand, p, i):
    """``p`` with entry ``i`` moved (to 71 % of its bounds; ``p`` is at 37 %)."""
    q = p.copy()
    q[i] = _at(cand, 0.71)[i]
    assert q[i] != p[i]
    return q


def test_the_cache_keys_name_every_parameter_the_model_reads(nominal_session):
    """Moving an entry of ``p`` outside ``DRIVE_SLOTS`` (and the timing) leaves the drive
    bit for bit, outside ``DYNAMICS_SLOTS`` the difference equations: what
    ``fit.Problem``'s caches rely on, for every candidate and pair."""
    from nmsid.analysis.gap.models import Candidate
    data = load_session(nominal_session)
    wn, zeta = np.full(len(data.sE_levels), 20.0), np.full(len(data.sE_levels), 0.7)
    for cand in _all_candidates():
        p = _at(cand, 0.37)
        drive_idx = set(cand.indices_at(Candidate.DRIVE_SLOTS, True))
        dyn_idx = set(cand.indices_at(Candidate.DYNAMICS_SLOTS))
        u0 = cand.drive(data, p)
        b0, a0 = cand.level_tfs(wn, zeta, p, 0.005)
        for i in set(range(cand.n_free())) - drive_idx - dyn_idx:
            q = _moved(cand, p, i)
            np.testing.assert_array_equal(cand.drive(data, q), u0, err_msg=cand.label)
            b, a = cand.level_tfs(wn, zeta, q, 0.005)
            np.testing.assert_array_equal(b, b0, err_msg=cand.label)
            np.testing.assert_array_equal(a, a0, err_msg=cand.label)
        for i in drive_idx - dyn_idx:
            b, a = cand.level_tfs(wn, zeta, _moved(cand, p, i), 0.005)
            np.testing.assert_array_equal(b, b0, err_msg=f"{cand.label} {i}")
        for i in dyn_idx - drive_idx:
            np.testing.assert_array_equal(cand.drive(data, _moved(cand, p, i)), u0,
                                          err_msg=f"{cand.label} {i}")


def test_cached_responses_equal_fresh_ones(nominal_session):
    """A Jacobian's sequence of points through one Problem (its caches in use) gives the
    residuals a fresh Problem computes for each point."""
    from nmsid.analysis.gap.fit import Problem
    from nmsid.analysis.gap.models import candidate
    from nmsid.protocols.effects import Effect
    data = load_session(nominal_session)
    cand = candidate(Effect.ACTIVATION_DYNAMICS, Effect.FATIGUE)
    n = len(data.sE_levels)
    wn, zeta = np.full(n, 20.0), np.full(n, 0.7)
    p = _at(cand, 0.37)
    points = [(wn, zeta, p), (wn * 1.01, zeta, p), (wn, zeta * 1.01, p)]
    points += [(wn, zeta, _moved(cand, p, i)) for i in range(cand.n_free())]
    points += [(wn, zeta, p), (wn * 1.01, zeta, p)]
    kept = Problem(data, cand)
    for w, z, q in points:
        r, Kp = kept.residual(w, z, q)
        r_fresh, Kp_fresh = Problem(data, cand).residual(w, z, q)
        np.testing.assert_array_equal(r, r_fresh)
        np.testing.assert_array_equal(Kp, Kp_fresh)
