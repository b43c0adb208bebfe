"""nmsid qc reports fatigue from the session's own structure: each kept repeat's gain
against its level's mean, on cumulative stimulation (no model)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nmsid.analysis.fatigue import gains_between_repeats
from nmsid.analysis.qc import assess_session
from nmsid.analysis.qc.table import as_json, format_table

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
from trial_sessions import TrialPhysiology, write_session

LEVELS = (0.3, 0.5, 0.7, 0.9, 1.0)


def test_gains_between_repeats_in_closed_form():
    t = np.arange(3000) / 1000.0
    shape = np.sin(2 * np.pi * 3 * t)
    trials = [SimpleNamespace(sE=0.5, fs_Hz=1000.0, steady_s=1.0, force_N=g * shape + 0.3 * t)
              for g in (1.0, 1.2, 0.8)]
    trials.append(SimpleNamespace(sE=0.9, fs_Hz=1000.0, steady_s=1.0, force_N=shape))
    g = gains_between_repeats(trials)
    np.testing.assert_allclose(g[:3], [1.0, 1.2, 0.8], rtol=1e-3)
    assert np.isnan(g[3])                      # a single repeat has no reference


@pytest.mark.parametrize("loss", [20.0, 0.0])
def test_qc_reports_fatigue_with_its_magnitude_only_when_there(tmp_path, loss):
    path = tmp_path / "q.h5"
    write_session(path, TrialPhysiology(levels=LEVELS, repeats=4, cv=(0.01, 0.005, 0.005),
                                        fatigue_pct=loss, chirp_s=6.0), seed=9)
    qc = assess_session(path)
    f = qc.fatigue
    assert f is not None and f.n_trials == 20
    text = format_table(qc)
    if loss:
        assert f.significant and abs(f.loss_pct - loss) < 4.0
        assert "fatigue: the gain lost" in text
    else:
        assert not f.significant and abs(f.loss_pct) < 3.0
        assert "the gain lost" not in text and "potentiation" not in text
    assert json.loads(as_json(qc))["fatigue"]["n_levels"] == len(LEVELS)
