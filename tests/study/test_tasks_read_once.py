"""A study task (identify + QC + gap of one session) reads its session file once."""

from __future__ import annotations

from nmsid.analysis.settings import IdentificationSettings
from nmsid.study.tasks import run_session
from nmsid.testing.sessions import write_gap_session


def test_study_task_reads_its_session_once(tmp_path, session_reads):
    path = write_gap_session(tmp_path / "s.h5", levels=(0.3, 0.6), repeats=2, steady_s=3.0,
                             chirp_s=6.0, seed=3)
    result = run_session(str(path), str(tmp_path / "out"), IdentificationSettings(), gap=True)
    assert result["ok"] is True and result["error"] == ""
    assert result["levels_identified"] == 2
    assert result["gap"]["best_effect"] == "none"     # an exact second order
    assert session_reads(path) == 1
    assert (tmp_path / "out" / "identify" / "parameters.csv").is_file()
    assert (tmp_path / "out" / "gap" / "gap_report.json").is_file()
