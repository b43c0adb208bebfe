"""``nmsid study`` marks a live or incomplete (killed, not recovered) session in its
reports (issue 26, 4)."""

from __future__ import annotations

from pathlib import Path

from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.session_file import Calibration, Trial
from nmsid.rig.session_log import SessionLog
from nmsid.study.report_html import _state_mark
from nmsid.study.runner import _line
from nmsid.study.tasks import run_session


def _killed_session(path: Path) -> None:
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=1,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    x = [0.1] * 50
    log.end_trial(Trial(sE=0.5, repeat=1, fs_Hz=100.0, rE=x, I_ext_mA=x, I_flex_mA=x,
                        force_N=x, extra_attrs={"schedule_index": 0}))
    log.close(publish=False)  # killed: the trial is only in the journal


def test_an_incomplete_session_is_marked_in_the_task_result_line_and_report(tmp_path):
    path = tmp_path / "k.h5"
    _killed_session(path)
    r = run_session(str(path), str(tmp_path / "out"), IdentificationSettings(), gap=False)
    assert r["session_state"] == "incomplete"
    assert "the journal holds 1 trial(s), the file 0" in r["state_note"]
    assert _state_mark(r) == " (INCOMPLETE)"
    assert "k.h5 [INCOMPLETE: " in _line(1, 1, r)
    assert _state_mark({"session_state": "finished"}) == ""
