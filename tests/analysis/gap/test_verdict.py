"""The verdict: logic on constructed facts and reports, the gap test on constructed
residuals, and whole diagnoses of sessions with known answers (clean rigs with and without
a sample hold, a baseline step inside one trial, a contaminated trial, excluded trials)."""

import json

import numpy as np
import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import diagnose
from nmsid.analysis.gap.verdict import decide, gap_test, narrow_band, sentence


@pytest.mark.parametrize("nominal,kind,remaining,expected", [
    (False, "none", False, "none"),
    (False, "effect", False, "none"),        # a candidate fitted a gap within noise
    (False, "pair", False, "none"),
    (True, "none", True, "unexplained"),
    (True, "effect", False, "effect"),
    (True, "effect", True, "effect"),        # with remaining.significant
    (True, "pair", True, "pair"),
    (True, "pair", False, "pair"),
])
def test_decide(nominal, kind, remaining, expected):
    assert decide(nominal, kind, remaining) == expected


def test_decide_refuses_an_unknown_kind():
    with pytest.raises(ValueError, match="kind"):
        decide(True, "maybe", True)


def _rows(rng, n_trials=30, n=1000, sd=0.1):
    ref = np.sin(np.linspace(0, 80, n))[None, :].repeat(n_trials, 0)
    return ref, rng.normal(0, sd, (n_trials, n)), np.full(n_trials, sd ** 2)


@pytest.mark.parametrize("sd", [0.005, 0.05, 0.2])
def test_gap_test_noise_only_is_not_significant(sd):
    rng = np.random.default_rng(int(sd * 1000))
    ref, r, N = _rows(rng, sd=sd)
    out = gap_test(r, N, ref, 1.0, 1.0, 300)
    assert not out.significant and out.median_ratio == pytest.approx(1, abs=0.1)


@pytest.mark.parametrize("shape", ["sine", "ramp", "harmonic"])
def test_gap_test_finds_a_deterministic_misfit_in_every_trial(shape):
    rng = np.random.default_rng(3)
    ref, r, N = _rows(rng)
    x = np.linspace(0, 1, r.shape[1])
    extra = {"sine": 0.05 * np.sin(40 * x), "ramp": 0.4 * (x - 0.5) ** 2,
             "harmonic": 0.04 * np.sin(160 * x)}[shape]
    out = gap_test(r + extra, N, ref, 1.0, 1.0, 300)
    assert out.significant and out.beyond_noise_pct > 1.0


def test_gap_test_does_not_rest_on_one_or_two_trials():
    rng = np.random.default_rng(5)
    ref, r, N = _rows(rng)
    r[[4, 17]] += 2.0 * np.exp(-0.5 * ((np.arange(r.shape[1]) - 500) / 60.0) ** 2)
    names = [f"t{i:03d}" for i in range(1, 31)]
    out = gap_test(r, N, ref, 1.0, 1.0, 300, names=names)
    assert not out.significant
    assert sorted(out.concentrated_in) == ["t005", "t018"]
    assert out.beyond_noise_pct > 10 * out.beyond_noise_pct_typical


def test_narrow_band_tells_a_line_from_an_oscillation():
    rng = np.random.default_rng(2)
    t = np.arange(1000) / 100.0
    line = rng.normal(0, 0.1, (20, 1000)) + 0.2 * np.sin(2 * np.pi * 13.0 * t)
    osc = rng.normal(0, 0.1, (20, 1000))
    for i in range(20):   # an oscillation whose frequency wanders from trial to trial
        f = 9.0 + 0.6 * rng.standard_normal()
        osc[i] += 0.2 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6))
    ref = np.ones((20, 1000))
    c_line = narrow_band(line, ref, None, 100.0, 25.0)
    c_osc = narrow_band(osc, ref, None, 100.0, 25.0)
    assert c_line[0]["kind"] == "line" and not c_line[0]["significant"]
    assert c_osc[0]["kind"] == "band" and c_osc[0]["significant"]
    assert 7.5 < c_osc[0]["f_Hz"] < 10.5


def test_sentences_say_it_in_words():
    nom = {"beyond_noise_pct_typical": 3.2}
    rem = {"beyond_noise_pct_typical": 1.1, "significant": True,
           "where_summary": "largest at sE = 1"}
    text = sentence("effect", "dead_time", nom, rem)
    assert "dead time" in text and "still significant" in text and "sE = 1" in text
    assert "none of the six" in sentence("unexplained", None, nom, dict(rem))
    assert "no unmodelled effect" in sentence("none", None, {"beyond_noise_pct_typical": 0.01},
                                              {"significant": False})


# -- whole diagnoses ------------------------------------------------------------------

@pytest.mark.parametrize("hold,noise_N", [(True, 0.005), (False, 0.005), (True, 0.06),
                                          (False, 0.06)])
def test_clean_session_is_none_whether_or_not_the_rig_holds_samples(write_synthetic,
                                                                    tmp_path, hold, noise_N):
    path = write_synthetic(tmp_path / "clean.h5", seed=11, hold=hold, noise_N=noise_N)
    diag = diagnose(load_session(path))
    assert diag.assessment["verdict"] == "none", diag.assessment["sentence"]
    assert diag.best_effect.value == "none"
    assert not diag.assessment["remaining"]["significant"]


@pytest.fixture(scope="module")
def step_diag(tmp_path_factory, write_synthetic):
    # the 8th trial written gets a 0.4 N baseline step 3.5 s into its chirp
    path = write_synthetic(tmp_path_factory.mktemp("step") / "step.h5", seed=6,
                           step=(7, 8.5, 0.4))
    return diagnose(load_session(path))


def test_step_drift_is_found_inside_one_trial(step_diag):
    steps = step_diag.assessment["remaining"]["where"]["baseline_steps"]
    hit = [s for s in steps if s["trial"] == "t008"]
    assert len(hit) == 1
    assert hit[0]["t_s"] == pytest.approx(3.5, abs=0.1)
    assert hit[0]["height_N"] == pytest.approx(0.4, rel=0.15)
    assert hit[0]["share_of_excess_pct"] > 80
    assert not [s for s in steps if s["trial"] != "t008"]


def test_folds_keep_the_step_of_a_held_out_trial(step_diag):
    """baseline_drift's held-out prediction of the stepped trial finds the step there."""
    drift = next(r for r in step_diag.candidates if r.label == "baseline_drift")
    i = [t.name for t in step_diag.data.trials].index("t008")
    ms = lambda r: float(np.mean(r[i] ** 2))     # noqa: E731
    noise = float(step_diag.data.steady_noise_N2[i])
    assert ms(step_diag.nominal.heldout_resid) > 20 * noise
    assert ms(drift.heldout_resid) < 2 * noise


def test_singles_and_pairs_share_one_effective_sample_basis(step_diag, write_synthetic,
                                                           tmp_path):
    path = write_synthetic(tmp_path / "pair.h5", seed=3, dead_time_s=0.02,
                           fatigue_per_100s=0.06)
    diag = diagnose(load_session(path))
    nus = {round(r.nu, 12) for r in diag.candidates + diag.pairs}
    assert len(diag.pairs) >= 1 and len(nus) == 1


def test_contaminated_trial_is_not_named_drift_and_exclusion_is_honoured(write_synthetic,
                                                                         tmp_path):
    path = write_synthetic(tmp_path / "bump.h5", seed=9, bump=([4], 8.0, 1.5, 3.0))
    diag = diagnose(load_session(path))
    assert diag.assessment["verdict"] == "none"
    assert diag.best_effect.value == "none"
    assert diag.assessment["nominal_gap"]["concentrated_in"] == ["t005"]
    # the same trial excluded upstream: not used at all, and listed in the report
    out = run_gap([path], tmp_path / "out", plots=False,
                  excluded={"t005": "voluntary contraction (qc)"})
    rep = json.loads((tmp_path / "out" / "gap_report.json").read_text())
    assert rep["excluded_trials"] == [{"trial": "t005",
                                       "reason": "voluntary contraction (qc)"}]
    assert rep["n_trials"] == 14 and rep["verdict"] == "none"
    assert "t005" not in [p["trial"] for p in rep["localization"]["nominal"]["position"]]
    assert not rep["nominal_gap"]["concentrated_in"]
    assert "no unmodelled effect is needed" in out.sessions[0]["verdict_sentence"]


def test_excluded_trials_never_reach_a_fit(nominal_session):
    data = load_session(nominal_session, excluded={"t002": "spike", "t010": "clipping"})
    names = [t.name for t in data.trials]
    assert "t002" not in names and "t010" not in names and len(names) == 13
    assert data.excluded == {"t002": "spike", "t010": "clipping"}


def test_the_unexplained_sentence_counts_the_registry_not_a_fixed_six(monkeypatch):
    from nmsid.analysis.gap import verdict
    nom = {"beyond_noise_pct_typical": 2.0, "significant": True}
    monkeypatch.setattr(verdict, "CANDIDATES", tuple(range(7)))
    assert "none of the seven candidate effects" in sentence("unexplained", None, nom, dict(nom))


def test_gap_test_keeps_its_report_form():
    rng = np.random.default_rng(3)
    ref = np.tile(np.sin(np.linspace(0, 60, 500)), (12, 1))
    r = rng.normal(0, 0.1, (12, 500))
    out = gap_test(r, np.full(12, 0.01), ref, 1.0, 1.0, 300)
    assert set(out.to_dict()) == {"n_trials", "significant", "beyond_noise_pct",
                                  "beyond_noise_pct_typical", "median_ratio", "z",
                                  "concentrated_in"}
    short = gap_test(r[:2], np.full(2, 0.01), ref[:2], 1.0, 1.0, 300)
    assert not short.significant and short.beyond_noise_pct is None
    assert "not tested" in short.to_dict()["note"]
