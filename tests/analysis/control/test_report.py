"""Tracking metrics against closed forms, and the report's honesty about aborted trials."""

import json
import math

import numpy as np
import pytest

from nmsid.analysis.control.errors import TrackingReportError
from nmsid.analysis.control.report import step_metrics, tracking_report, write_report
from nmsid.analysis.control.targets import Target
from nmsid.protocols.session_file import Calibration, Session, Trial

FS = 1000.0
STEP = Target("steps", "step", {"levels_N": [0.0, 2.0], "hold_s": 2.0}, 4.0, 0.5)


def _response(kind: str) -> np.ndarray:
    """Force for STEP: first-order (tau 0.1 s) or second-order (zeta 0.3, wn 20) from the
    step at t = lead + hold."""
    t = np.arange(int((STEP.lead_s + STEP.duration_s) * FS)) / FS
    s = np.clip(t - (STEP.lead_s + 2.0), 0, None)
    if kind == "first":
        y = 1 - np.exp(-s / 0.1)
    else:
        z, wn = 0.3, 20.0
        wd = wn * math.sqrt(1 - z * z)
        y = 1 - np.exp(-z * wn * s) * (np.cos(wd * s) + z / math.sqrt(1 - z * z) * np.sin(wd * s))
    return 2.0 * y


def test_first_order_step_settles_at_tau_ln20_without_overshoot():
    ov, st, unsettled = step_metrics(_response("first"), STEP, FS)
    assert ov == pytest.approx(0.0, abs=1e-12)
    assert st == pytest.approx(0.1 * math.log(20), abs=2 / FS) and unsettled == 0


def test_second_order_overshoot_matches_the_closed_form():
    ov, _, _ = step_metrics(_response("second"), STEP, FS)
    z = 0.3
    assert ov == pytest.approx(100 * math.exp(-z * math.pi / math.sqrt(1 - z * z)), rel=1e-3)


def _trial(name, controller, force, status="completed"):
    n = force.size
    return Trial(sE=0.8, repeat=1, fs_Hz=FS, rE=np.full(n, 0.5), I_ext_mA=np.full(n, 5.0),
                 I_flex_mA=np.full(n, 4.0), force_N=force, status=status,
                 abort_reason="" if status == "completed" else "estop: pressed", name=name,
                 extra_attrs={"trial_kind": "tracking", "controller": controller,
                              "target_json": STEP.to_json(),
                              "stream_json": json.dumps({"latency_median_s": 0.0055})})


def test_report_means_per_controller_and_says_what_was_left_out(tmp_path):
    ideal = STEP.force_at(np.arange(int(4.5 * FS)) / FS)
    s = Session(path=str(tmp_path / "x.h5"), participant="P", created_utc="", software="",
                calibration=Calibration(2, 9.5, 1.5, 8, 0.5, 5),
                trials=[_trial("t001", "twin", ideal + 0.1),
                        _trial("t002", "baseline", ideal + 0.4),
                        _trial("t003", "baseline", ideal[:1000], status="aborted")])
    rep = tracking_report(s)
    # a constant error e: RMSE = e, the target's range is 2 N
    assert rep.controllers["twin"]["rmse_pct_of_range"] == pytest.approx(5.0)
    assert rep.controllers["baseline"]["rmse_pct_of_range"] == pytest.approx(20.0)
    assert rep.controllers["twin_over_baseline"] == pytest.approx(0.25)
    assert rep.controllers["baseline"]["n_aborted"] == 1
    assert any("1 aborted trial(s) (1000 samples) left out" in n for n in rep.notes)
    write_report(s, tmp_path)
    data = json.loads((tmp_path / "tracking.json").read_text())
    assert data["controllers"]["twin"]["rmse_pct_of_range"] == pytest.approx(5.0)
    assert "| twin |" in (tmp_path / "report.md").read_text()
    s.trials = []
    with pytest.raises(TrackingReportError, match="no tracking trials"):
        tracking_report(s)
