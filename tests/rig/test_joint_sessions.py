"""Sessions on the knee and the ankle (docs/joints.md): ``nmsid run --joint`` on the
simulated rig (fast clock) records the joint, calibrates in the joint's unit, holds the
interlock at the joint's limit and labels the identification with its quantity."""

import contextlib
import json

import numpy as np
import pytest

from nmsid.cli import main
from nmsid.protocols.config import config_from_dict
from nmsid.protocols.joints import JOINTS
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine
from nmsid.rig.observer import TripPolicy
from nmsid.sim_backends.joint_participants import template_participant
from nmsid.sim_backends.rig import make_sim_rig

SHORT = """
participant = "J01"
[protocol]
sE_levels = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8]
repeats = 1
steady_s = 1.0
chirp_s = 3.0
[calibration]
hold_s = 1.0
baseline_s = 0.2
rest_s = 0.2
"""


@pytest.mark.parametrize("joint", ["knee", "ankle"])
def test_run_joint_end_to_end(tmp_path, joint, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT)
    out = tmp_path / "s.h5"
    code = main(["run", "--backend", "sim", "--joint", joint, "--config", str(cfg),
                 "--out", str(out), "--seed", "4", "--quiet"])
    assert code == 0, capsys.readouterr().err
    j = JOINTS[joint]
    assert validate_session(out) == []
    s = read_session(out)
    assert (s.attrs["joint"], s.attrs["measured_unit"]) == (joint, j.unit)
    assert json.loads(s.attrs["joint_json"])["extensor_muscles"] == j.extensor_muscles
    assert s.config["joint"] == joint
    assert s.config["interlock"]["force_limit_N"] == j.limit
    # the ramps found the template's reference currents with the joint's thresholds
    assert (s.calibration.Fmin_N, s.calibration.Fmax_N) == (j.Fmin, j.Fmax)
    assert (s.calibration.Iemin_mA, s.calibration.Iemax_mA) == (2.0, 9.5)
    peak = max(float(np.max(np.abs(t.force_N))) for t in s.trials)
    # torques of a knee / ankle in N m (beyond any elbow's Fmax in N), under the limit
    assert JOINTS["elbow"].Fmax < peak < j.limit
    analysis = tmp_path / "s-analysis"
    tables = (analysis / "tables.txt").read_text()
    assert f"{joint} torque (N m)" in tables and "Kp (N m)" in tables
    sel = json.loads((analysis / "model_selection.json").read_text())
    assert sel["measured_unit"] == "N m" and sel["joint"] == joint
    twin = json.loads((analysis / "twin.json").read_text())
    assert (twin["joint"], twin["measured_unit"]) == (joint, "N m")


def test_resume_refuses_a_new_joint(tmp_path, capsys):
    code = main(["run", "--backend", "sim", "--resume", str(tmp_path / "x.h5"),
                 "--joint", "knee"])
    assert code == 2


def test_the_interlock_trips_at_the_knees_limit_in_n_m(tmp_path):
    # a limit below the torques this participant produces (the template knee's Kp(1.0) is
    # 90 N m per unit rE: +/-45 N m at sE 1): the 30 N m limit trips in the trial and says
    # so in N m; output ends at zero (calibration entered by hand: no ramp reaches 30 N m)
    cfg = config_from_dict({"joint": "knee", "participant": "J02", "seed": 1,
                            "protocol": {"sE_levels": [1.0], "repeats": 1, "steady_s": 1.0,
                                         "chirp_s": 2.0, "rest_s": 0.0},
                            "calibration": {"baseline_s": 0.2, "rest_s": 0.2, "manual": {
                                "Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                                "Ifmax_mA": 8.0}},
                            "interlock": {"force_limit_N": 30.0}})
    rig = make_sim_rig(template_participant("knee", seed=2))
    eng = Engine(cfg, rig, tmp_path / "t.h5", trip_policy=TripPolicy.END_SESSION)
    eng.run()
    s = read_session(tmp_path / "t.h5")
    trips = [e for e in s.events if "torque" in e.detail and "N m" in e.detail]
    assert trips and "beyond the limit +/-30 N m" in trips[0].detail
    assert s.trials[0].status == "aborted"
    assert rig.output_zero_events


def test_cocontraction_sweep_from_the_command_line(tmp_path, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT)
    out = tmp_path / "c.h5"
    code = main(["run", "--backend", "sim", "--joint", "ankle", "--config", str(cfg),
                 "--out", str(out), "--seed", "4", "--cocontraction", "0.3", "--quiet"])
    assert code == 0, capsys.readouterr().err
    s = read_session(out)
    assert s.attrs["session_kind"] == "cocontraction" and s.attrs["joint"] == "ankle"
    assert [t.sE for t in s.trials] == [0.3, 0.4, 0.5, 0.6, 0.7, 0.8]   # listed order
    assert all(np.all(t.rE == 0.3) and t.n_samples == 8000 for t in s.trials)
    assert not (tmp_path / "c-analysis").exists()       # a sweep is not identified


@pytest.mark.parametrize("extra", [["--cocontraction", "1.5"], ["--cocontraction", "nan"],
                                   ["--cocontraction", "0.5", "--track", "x.json"]])
def test_cocontraction_option_refusals(tmp_path, extra, capsys):
    x = tmp_path / "x.json"
    x.write_text("{}")
    extra = [str(x) if a == "x.json" else a for a in extra]
    bad_value = extra[1] in ("1.5", "nan")     # argparse refuses it (exit 2)
    with pytest.raises(SystemExit) if bad_value else contextlib.nullcontext():
        code = main(["run", "--backend", "sim", "--out", str(tmp_path / "c.h5"), "--quiet",
                     *extra])
        assert code == 2
    assert not (tmp_path / "c.h5").exists()


def test_a_sweep_is_not_identified(tmp_path, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT)
    out = tmp_path / "c.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--cocontraction", "0.5", "--quiet"]) == 0
    code = main(["identify", str(out), "--out", str(tmp_path / "id"), "--no-figures"])
    err = capsys.readouterr()
    assert code != 0 and "co-contraction sweep" in err.out + err.err
