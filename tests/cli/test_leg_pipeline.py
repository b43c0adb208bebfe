"""Issue 41's done-when, per leg joint, from the command line: a session on the built-in
MyoLeg participant (``--participant-model musculoskeletal --joint knee|ankle``:
calibration ramps, 45 trials, identify), then ``nmsid gap``, ``nmsid design``, ``nmsid
control design`` and a tracking session on the twin's controller, each with the joint's
labels, unit (N m) and limits. Fast clock; the trials are short (1 s lead-in + 3 s chirp
instead of 5 + 15 s) so that one joint's whole pipeline stays near half a minute.

Skipped only when the optional 'mujoco' extra (mujoco, myo_sim) is not installed."""

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("myo_sim")

from nmsid.cli import main  # noqa: E402
from nmsid.protocols.joints import JOINTS  # noqa: E402
from nmsid.protocols.session_file import read_session, validate_session  # noqa: E402

SHORT = """
[protocol]
repeats = 3
steady_s = 1.0
chirp_s = 3.0
[calibration]
hold_s = 0.6
baseline_s = 0.2
rest_s = 0.2
"""


@pytest.mark.parametrize("joint", ["knee", "ankle"])
def test_a_myoleg_session_runs_the_whole_pipeline(tmp_path, monkeypatch, capsys, joint):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "short.toml").write_text(SHORT, encoding="utf-8")
    j = JOINTS[joint]
    sim = ["--backend", "sim", "--joint", joint, "--participant-model", "musculoskeletal",
           "--config", "short.toml", "--quiet"]
    # 1. calibration + the 15 sE x 3 schedule + identify
    assert main(["run", *sim, "--out", "id.h5", "--seed", "3"]) == 0, capsys.readouterr().err
    assert validate_session("id.h5") == []
    s = read_session("id.h5")
    assert len(s.trials) == 45 and all(t.status == "completed" for t in s.trials)
    assert (s.attrs["joint"], s.attrs["measured_unit"]) == (joint, "N m")
    assert s.attrs["participant_model"] == "musculoskeletal"
    assert s.config["interlock"]["force_limit_N"] == j.limit
    assert (s.calibration.Fmin_N, s.calibration.Fmax_N) == (j.Fmin, j.Fmax)
    peak = max(float(np.max(np.abs(t.force_N))) for t in s.trials)
    assert JOINTS["elbow"].Fmax < peak < j.limit           # torques in N m, under the limit
    tables = (tmp_path / "id-analysis" / "tables.txt").read_text()
    assert f"{joint} torque (N m)" in tables and "Kp (N m)" in tables
    twin = json.loads((tmp_path / "id-analysis" / "twin.json").read_text())
    assert (twin["joint"], twin["measured_unit"]) == (joint, "N m")
    # 2. the gap: its report and its twin in the joint's unit
    assert main(["gap", "id.h5", "--out", "gap", "--no-figures", "--no-muscle",
                 "--no-pairs"]) == 0
    rep = json.loads((tmp_path / "gap" / "gap_report.json").read_text())
    assert (rep["joint"], rep["measured_unit"]) == (joint, "N m")
    gap_twin = json.loads((tmp_path / "gap" / "twin.json").read_text())
    assert (gap_twin["joint"], gap_twin["measured_unit"]) == (joint, "N m")
    assert "residual power (N m)^2" in (tmp_path / "gap" / "report.html").read_text()
    # 3. the protocol design: for this joint (its noise, its protocol file)
    assert main(["design", "--twin", "id-analysis/twin.json", "--out", "des",
                 "--validate", "0"]) == 0
    toml = (tmp_path / "des" / "protocol.toml").read_text()
    assert f'joint = "{joint}"' in toml
    assert json.loads((tmp_path / "des" / "design.json").read_text())["joint"] == joint
    # 4. the controller: in N m
    capsys.readouterr()
    assert main(["control", "design", "id-analysis/twin.json", "--out", "ctl"]) == 0
    assert "rE/(N m)" in capsys.readouterr().out
    ctl = json.loads((tmp_path / "ctl" / "controller.json").read_text())
    assert (ctl["joint"], ctl["measured_unit"]) == (joint, "N m")
    lo, hi = ctl["force_range_N"]
    assert -j.limit < lo < hi < j.limit
    assert f"({joint}, N m)" in (tmp_path / "ctl" / "design.md").read_text()
    # 5. a tracking session on it, and its report
    mid = 0.5 * (lo + hi)
    (tmp_path / "target.csv").write_text(
        f"t_s,force_N\n0,{mid:g}\n0.5,{hi:g}\n1.0,{lo:g}\n1.5,{mid:g}\n", encoding="utf-8")
    assert main(["run", *sim, "--track", "ctl/controller.json", "--target", "target.csv",
                 "--out", "track.h5"]) == 0
    tr = read_session("track.h5")
    assert tr.attrs["joint"] == joint and tr.attrs["session_kind"] == "tracking"
    assert [t.status for t in tr.trials] == ["completed"] * 3
    assert main(["control", "report", "track.h5", "--out", "rep"]) == 0
    assert "max error N m" in (tmp_path / "rep" / "report.md").read_text()
    # a controller of this joint on a session of another is refused before any device
    other = "ankle" if joint == "knee" else "knee"
    capsys.readouterr()
    code = main(["run", "--backend", "sim", "--joint", other, "--track", "ctl/controller.json",
                 "--out", "other.h5", "--quiet"])
    assert code == 2 and f"designed on a {joint} twin" in capsys.readouterr().err
    assert not (tmp_path / "other.h5").exists()
