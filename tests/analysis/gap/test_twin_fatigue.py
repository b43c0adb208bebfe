"""Fatigue found by the gap goes into twin.json, and ``nmsid twin simulate`` reproduces
the loss (issue 40 item 4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.gap.diagnose import GapSettings
from nmsid.cli import main
from nmsid.testing.sessions import write_physiology_session


@pytest.fixture(scope="module")
def fatigued(tmp_path_factory):
    """25 % lost linearly under 10/5/5 % trial-to-trial scatter: the verdict is within
    scatter (fatigue is not the named effect), the gain-based fatigue is significant."""
    tmp = tmp_path_factory.mktemp("twinfat")
    path = write_physiology_session(tmp / "f.h5", seed=2, fatigue=("linear", 0.25),
                                    randomisation="full") and tmp / "f.h5"
    out = tmp / "out"
    run_gap([path], out, plots=False, settings=GapSettings(try_muscle=False))
    return out


def test_significant_fatigue_is_written_into_the_twin(fatigued):
    rep = json.loads((fatigued / "gap_report.json").read_text())
    twin = json.loads((fatigued / "twin.json").read_text())
    assert rep["fatigue"]["significant"]
    assert "fatigue" not in (rep["best_effect"], *(rep.get("best_pair") or []))
    (entry,) = [e for e in twin["effects"] if e["name"] == "fatigue"]
    assert entry["params"]["gain_loss_pct"] == pytest.approx(rep["fatigue"]["loss_pct"])
    assert entry["params"]["reference_stim_s"] == pytest.approx(
        rep["fatigue"]["total_stim_s"])
    assert rep["fatigue_in_twin"]["kp_scale"] > 1.0      # the twin starts unfatigued
    assert 15.0 < rep["fatigue"]["loss_pct"] < 35.0      # truth 25 %


def test_twin_simulate_reproduces_the_loss(fatigued, tmp_path):
    twin = json.loads((fatigued / "twin.json").read_text())
    loss = [e for e in twin["effects"] if e["name"] == "fatigue"][0]["params"]
    fs = 50.0
    t = np.arange(int(loss["reference_stim_s"] * fs)) / fs
    rE = 0.5 + 0.3 * np.sin(2 * np.pi * 1.0 * t)
    csv = tmp_path / "in.csv"
    csv.write_text("rE\n" + "\n".join(f"{v:.6f}" for v in rE) + "\n")
    out = tmp_path / "f.csv"
    assert main(["twin", "simulate", str(fatigued / "twin.json"), "--input", str(csv),
                 "--sE", "0.6", "--fs-Hz", f"{fs:g}", "--out", str(out)]) == 0
    data = np.genfromtxt(out, delimiter=",", names=True)
    f = data[data.dtype.names[-1]]
    n = int(10 * fs)
    first = np.ptp(f[n:2 * n])          # after the start-up transient
    last = np.ptp(f[-n:])
    c_first, c_last = 1.5 * n / fs, t[-1] - 0.5 * n / fs
    want = (1 - loss["gain_loss_pct"] / 100) ** ((c_last - c_first) / loss[
        "reference_stim_s"])
    assert last / first == pytest.approx(want, rel=0.03)
