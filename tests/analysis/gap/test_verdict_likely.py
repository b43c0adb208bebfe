"""The third answer (issue 40): a candidate that wins on evidence but that trial-to-trial
scatter hides from the held-out test is "likely X, not separable from scatter", never
"something else is at work"; and the muscle-twin sentence matches its numbers."""

from __future__ import annotations

import json

import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.gap.diagnose import GapSettings
from nmsid.analysis.gap.verdict import Likely, sentence
from nmsid.testing.sessions import write_physiology_session


@pytest.mark.parametrize("effect", [
    {"recruitment": ("sigmoid", 9.0, 0.5)},
    {"asymmetry": (0.65, 1.2), "randomisation": "full"},
])
def test_a_library_effect_under_scatter_is_likely_not_something_else(tmp_path, effect):
    path = tmp_path / "s.h5"
    write_physiology_session(path, seed=11, cv=(0.10, 0.05, 0.05), **effect)
    out = tmp_path / "out"
    run_gap([path], out, plots=False, settings=GapSettings(try_muscle=False))
    rep = json.loads((out / "gap_report.json").read_text())
    want = "recruitment_nonlinearity" if "recruitment" in effect else \
        "flexor_extensor_asymmetry"
    assert "something else" not in rep["verdict_sentence"]
    if rep["verdict"] == "likely":
        lk = rep["likely"]
        assert lk["label"] == want and lk["delta_ic"] < -10 and 0 < lk["shrink_pct"] < 10
        assert rep["verdict_sentence"].startswith("Likely ")
        assert "not separable from scatter" in rep["verdict_sentence"]
        assert f"dIC {lk['delta_ic']:.0f}" in rep["verdict_sentence"]
        assert rep["best_effect"] == "none"          # the twin stays nominal
    else:                                             # scatter did not hide it: named
        assert rep["verdict"] in ("effect", "pair")
        assert want in (rep["best_effect"], *(rep.get("best_pair") or []))


def _likely(more):
    return Likely(label="recruitment_nonlinearity", delta_ic=-812.0, shrink_pct=6.1,
                  heldout_nrmse_pct=14.1, nominal_nrmse_pct=15.0, z_heldout=1.7,
                  more_repeats=more, trial_to_trial_pct=12.0, systematic_pct=3.0)


def test_the_likely_sentence_gives_candidate_evidence_and_repeats_to_decide():
    nom = {"beyond_noise_pct_typical": 12.4}
    text = sentence("likely", "recruitment_nonlinearity", nom, {}, likely=_likely(4))
    assert text.startswith("Likely non-linear motor-unit recruitment")
    assert "dIC -812" in text and "6.1 %" in text
    assert "about 4 more repeats of each sE would decide" in text
    assert "something else" not in text
    one = sentence("likely", "recruitment_nonlinearity", nom, {}, likely=_likely(1))
    assert "about 1 more repeat of each sE" in one


@pytest.mark.parametrize("ratio,physics", [(1.4, True), (2.99, True), (3.48, False)])
def test_muscle_physics_only_within_the_stated_multiple_of_the_floor(ratio, physics):
    """Issue 40: 3.48x the floor was called "the remainder is muscle physics"."""
    text = sentence("muscle_twin", "muscle_twin", {"beyond_noise_pct_typical": 5.0},
                    {"beyond_noise_pct_typical": 1.0}, muscle_to_floor=ratio)
    assert text.startswith("The remainder is muscle physics") is physics
    if not physics:
        assert f"{ratio:.1f}x the noise floor" in text and "within 3x" in text
