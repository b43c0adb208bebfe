"""The verdict knows trial-to-trial physiology: a misfit that differs between repeats is
trial-to-trial variability, not a model gap; library effects are still named with it.
Sessions from bench/trial_sessions.py (scipy's exact discretisation, not nmsid's simulator)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

from nmsid.analysis.fatigue import FatigueResult
from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose
from nmsid.analysis.gap.verdict import GapTest, GapVerdict, split_misfit

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
from trial_sessions import TrialPhysiology, write_session

LEVELS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def _diagnose(tmp_path, seed, **kw):
    path = tmp_path / f"s{seed}.h5"
    write_session(path, TrialPhysiology(levels=LEVELS, chirp_s=8.0, **kw), seed)
    return diagnose(load_session(path), GapSettings(try_muscle=False))


def test_split_counts_a_common_part_only_when_significant_and_material():
    per_trial = GapTest(n_trials=24, beyond_noise_pct_typical=10.0, significant=True)
    small = split_misfit(per_trial, GapTest(8, beyond_noise_pct_typical=0.3, significant=True))
    assert small.within_scatter and not small.systematic_significant
    assert small.trial_to_trial_pct == pytest.approx(math.sqrt(100 - 0.09))
    big = split_misfit(per_trial, GapTest(8, beyond_noise_pct_typical=0.6, significant=True))
    assert big.systematic_significant and not big.within_scatter
    noisy = split_misfit(per_trial, GapTest(8, beyond_noise_pct_typical=3.0, significant=False))
    assert noisy.within_scatter
    assert not split_misfit(GapTest(24, significant=False), None).within_scatter
    assert split_misfit(per_trial, None).to_dict() == {
        "systematic_pct": None, "trial_to_trial_pct": None, "within_scatter": False,
        "systematic_significant": None}


def test_scatter_between_repeats_is_not_called_a_gap(tmp_path):
    diag = _diagnose(tmp_path, 1)
    v = diag.assessment
    assert isinstance(v, GapVerdict) and v.verdict == "none" and v.label is None
    nom = v.nominal_gap
    assert nom["within_scatter"] and nom["beyond_noise_pct_typical"] > 5.0
    assert nom["systematic_pct"] < 0.05 * nom["trial_to_trial_pct"]
    assert "trial-to-trial variability, not a model gap" in v.sentence
    assert f"{nom['trial_to_trial_pct']:.2f} %" in v.sentence
    assert f"{diag.noise_floor_nrmse_pct:.2f} %" in v.sentence
    assert not v.remaining["significant"]
    # the former dict's reading still works
    assert v["verdict"] == "none" and v.get("nothing", 3) == 3
    assert isinstance(v.fatigue, FatigueResult) and not v.fatigue.significant
    assert v.as_dict()["fatigue"]["n_trials"] == len(LEVELS) * 3


def test_a_dead_time_is_named_and_the_scatter_left_is_not_a_remainder(tmp_path):
    v = _diagnose(tmp_path, 2, dead_time_s=0.02).assessment
    assert v.verdict == "effect" and v.label == "dead_time"
    assert v.nominal_gap["systematic_significant"]
    assert v.remaining["within_scatter"] and not v.remaining["significant"]
    assert "which is trial-to-trial variability" in v.sentence


def test_fatigue_is_reported_by_the_gap_with_its_magnitude(tmp_path):
    v = _diagnose(tmp_path, 3, cv=(0.01, 0.005, 0.005), fatigue_pct=25.0).assessment
    f = v.fatigue
    assert f.significant and abs(f.loss_pct - 25.0) < 5.0
    assert v.verdict in ("effect", "pair") and "fatigue" in v.label
    assert f"the gain lost {f.loss_pct:.1f} % (95 % CI" in v.sentence
