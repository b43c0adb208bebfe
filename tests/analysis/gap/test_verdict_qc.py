"""The verdict weighed by what quality control removed (issue 40): excluded trials and
why in the sentence, a verdict on fewer than ``min_trial_share`` of the trials marked
partial, and a lead-in noise estimate that a baseline drift does not inflate."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.gap.data import load_session
from nmsid.testing.sessions import write_gap_session, write_physiology_session

NINE = {"levels": (0.3, 0.6, 0.9), "repeats": 3, "steady_s": 3.0, "chirp_s": 8.0, "seed": 1}


@pytest.fixture(scope="module")
def nine(tmp_path_factory):
    return write_gap_session(tmp_path_factory.mktemp("qc") / "s.h5", **NINE)


def _run(path, tmp_path, excluded) -> dict:
    out = tmp_path / "out"
    run_gap([path], out, plots=False, excluded=excluded)
    return json.loads((out / "gap_report.json").read_text())


def test_one_excluded_trial_is_named_with_its_reason(nine, tmp_path):
    rep = _run(nine, tmp_path, {"t003": "baseline step: 1.5 N at 9 s"})
    s = rep["verdict_sentence"]
    assert s.startswith("[Quality control excluded 1 of 9 trials (1 baseline step: t003)")
    assert "rests on the other 8" in s
    assert rep["qc"]["n_excluded"] == 1 and rep["qc"]["partial"] is False


def test_a_verdict_on_few_trials_is_marked_partial(nine, tmp_path):
    ex = {"t001": "clipped (force at the sensor's range)", "t004": "baseline step",
          "t007": "clipped (force at the sensor's range)"}
    rep = _run(nine, tmp_path, ex)
    s = rep["verdict_sentence"]
    assert s.startswith("[Partial verdict: quality control excluded 3 of 9 trials")
    assert "2 clipped" in s and "1 baseline step" in s and "only 6 (67 %" in s
    assert rep["qc"]["partial"] is True and rep["qc"]["share_used"] == pytest.approx(6 / 9)


def test_no_exclusion_leaves_the_sentence_alone(nine, tmp_path):
    rep = _run(nine, tmp_path, None)
    assert not rep["verdict_sentence"].startswith("[")
    assert rep["qc"]["n_excluded"] == 0


@pytest.mark.parametrize("noise_N", [0.01, 0.05])
def test_the_lead_in_noise_is_robust_to_a_baseline_drift(tmp_path, noise_N):
    """The same noise with and without a slow wander (0.4 N, below 0.1 Hz): the drift
    raises the estimate by at most 25 % (a linear detrend let it in several-fold)."""
    kw = {"levels": (0.4, 0.8), "repeats": 3, "noise_N": noise_N, "seed": 3}
    clean = load_session(write_physiology_session(tmp_path / "c.h5", **kw) and
                         tmp_path / "c.h5")
    drift = load_session(write_physiology_session(tmp_path / "d.h5", drift=(0.4, 0.03),
                                                  **kw) and tmp_path / "d.h5")
    a = np.sqrt(np.median(clean.steady_noise_N2))
    b = np.sqrt(np.median(drift.steady_noise_N2))
    old = np.sqrt(np.median(np.mean(drift.steady_N ** 2, axis=1)))  # the linear detrend
    assert b < 1.25 * a, (a, b)
    assert old > 1.5 * b, (old, b)
