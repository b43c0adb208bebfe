"""Every gap verdict reached from a whole session file built for it (``run_gap`` on the
file, as ``nmsid gap`` runs it).

Short sessions (3 sE x 2 repeats, 3 s lead-in + 8 s chirp) from
:func:`nmsid.testing.sessions.write_gap_session`, written independently of ``analysis.gap``:

- ``none``: the exact second-order participant;
- ``effect``: the force answers 30 ms late (a dead time);
- ``pair``: a 20 ms dead time and fatigue (12 % gain loss per 100 s of stimulation);
- ``unexplained``: co-contraction, even in the drive, which none of the candidates (each odd
  in the drive) can produce.
"""

from __future__ import annotations

import json

import pytest

from nmsid.analysis.gap.api import run_gap
from nmsid.testing.sessions import write_gap_session

SHORT = {"levels": (0.3, 0.6, 0.9), "repeats": 2, "steady_s": 3.0, "chirp_s": 8.0, "seed": 1}


def _report(tmp_path, **effects) -> dict:
    path = write_gap_session(tmp_path / "s.h5", **SHORT, **effects)
    out = tmp_path / "out"
    run_gap([path], out, plots=False)
    return json.loads((out / "gap_report.json").read_text())


def test_exact_second_order_is_none(tmp_path):
    rep = _report(tmp_path)
    assert rep["verdict"] == "none"
    assert rep["best_effect"] == "none"
    assert rep["remaining"]["significant"] is False
    assert "no unmodelled effect is needed" in rep["verdict_sentence"]


def test_dead_time_is_an_effect(tmp_path):
    rep = _report(tmp_path, dead_time_s=0.030)
    assert rep["verdict"] == "effect"
    assert rep["best_effect"] == "dead_time"
    assert rep.get("best_pair") is None
    assert rep["best_params"]["L_s"] == pytest.approx(0.030, rel=0.15)
    assert rep["verdict_sentence"].startswith("Adding ")


def test_dead_time_and_fatigue_are_a_pair(tmp_path):
    rep = _report(tmp_path, dead_time_s=0.020, fatigue_per_100s=0.12, blocks=False)
    assert rep["verdict"] == "pair"
    assert sorted(rep["best_pair"]) == ["dead_time", "fatigue"]


def test_co_contraction_is_unexplained(tmp_path):
    rep = _report(tmp_path, co_contraction=(0.5, 0.05))
    assert rep["verdict"] == "unexplained"
    assert rep["best_effect"] == "none"
    assert rep["remaining"]["significant"] is True
    assert "none of the six candidate effects" in rep["verdict_sentence"]
