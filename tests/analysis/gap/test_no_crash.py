"""Every contract-valid session gets a report from the default ``nmsid gap`` (figures on):
a muscle-twin fit that does not converge is a row that says so, never a crash (issue 40).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.analysis.muscle import fit as muscle_fit
from nmsid.cli import main
from nmsid.cli.gap_command import session_lines
from nmsid.testing.sessions import write_gap_session

SHORT = {"levels": (0.3, 0.6, 0.9), "repeats": 2, "steady_s": 3.0, "chirp_s": 8.0, "seed": 1}


@pytest.fixture(scope="module")
def unexplained_session(tmp_path_factory):
    """Co-contraction: the template leaves a significant gap, so the muscle twin is
    tried."""
    return write_gap_session(tmp_path_factory.mktemp("crash") / "cc.h5", **SHORT,
                             co_contraction=(0.5, 0.05))


def _overflowing(theta, rE, sE, dt_s):
    """A muscle model whose simulation overflows (what a stiff, unstable parameter set
    does in float64)."""
    th = np.atleast_2d(theta)
    return np.full((th.shape[0], rE.shape[0], rE.shape[1]), np.inf)


def test_a_muscle_fit_that_overflows_is_a_row_not_a_crash(unexplained_session, tmp_path,
                                                          monkeypatch, capsys):
    monkeypatch.setattr(muscle_fit, "simulate_batch", _overflowing)
    out = tmp_path / "out"
    assert main(["gap", str(unexplained_session), "--out", str(out)]) == 0   # figures on
    rep = json.loads((out / "gap_report.json").read_text())
    m = rep["muscle_twin"]
    assert m["converged"] is False and m["supported"] is False
    assert m["heldout"]["muscle_nrmse_pct"] is None
    assert "did not converge" in m["note"]
    assert rep["verdict"] != "muscle_twin"
    printed = capsys.readouterr().out
    assert "muscle twin: not scored" in printed
    assert (out / "report.html").exists() and (out / "where.png").exists()
    assert not (out / "muscle.png").exists()
    assert "figures_failed" not in rep


def test_printed_lines_survive_every_figure_missing():
    """A report whose figures are all None (JSON of NaN) prints n/a, not a TypeError."""
    rep = {"session": "s.h5", "verdict": "unexplained", "best_effect": "none",
           "heldout": dict.fromkeys(("nominal_nrmse_pct", "augmented_nrmse_pct", "shrink_pct",
                                     "noise_floor_nrmse_pct", "sensor_floor_nrmse_pct")),
           "verdict_sentence": "x", "elapsed_s": None, "evidence": {"summary": []},
           "muscle_twin": {"supported": False, "converged": True, "fit_s": None,
                           "not_determined": [],
                           "heldout": {"nominal_nrmse_pct": None, "template": "nominal",
                                       "template_nrmse_pct": None, "muscle_nrmse_pct": None,
                                       "noise_floor_nrmse_pct": None}}}
    lines = session_lines(rep)
    assert "n/a" in lines[0] and "n/a" in lines[2]


def test_a_failing_figure_costs_the_figure_not_the_report(unexplained_session, tmp_path,
                                                          monkeypatch):
    from nmsid.analysis.gap import plots

    def broken(*args, **kw):
        raise TypeError("unsupported operand type(s) for +: 'int' and 'NoneType'")

    monkeypatch.setattr(plots, "plot_frequency", broken)
    out = tmp_path / "out"
    run_gap([unexplained_session], out, settings=None, plots=True)
    rep = json.loads((out / "gap_report.json").read_text())
    assert rep["figures_failed"][0]["figure"] == "frequency.png"
    assert "frequency.png" not in rep["figures"] and "where.png" in rep["figures"]
