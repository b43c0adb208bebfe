"""A participant's twin of several joints in one file (analysis/joint_twins.py)."""

import json

import numpy as np
import pytest

from nmsid.analysis.errors import TwinFileError
from nmsid.analysis.joint_twins import joint_twins_to_dict, load_joint_twins, save_joint_twins
from nmsid.analysis.twin import Curve, Twin


def _twin(joint, kp, wn, zeta, quantity="torque", unit="N m"):
    return Twin("P01", {"Kp": Curve("exponential", [kp, 1.9]),
                        "wn_rad_s": Curve("quadratic", [wn, 10.0, -8.0]),
                        "zeta": Curve("linear", [zeta, 0.2])}, (0.3, 1.0),
                offset_N=Curve("constant", [0.4]), joint=joint,
                measured_quantity=quantity, measured_unit=unit,
                calibration={"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                             "Ifmax_mA": 8.0, "Fmin_N": 5.0, "Fmax_N": 50.0})


TWINS = [_twin("elbow", 1.35, 20.0, 0.4, "force", "N"), _twin("knee", 13.5, 9.0, 0.7),
         _twin("ankle", 5.4, 7.0, 0.8)]


def test_three_joints_in_one_file_each_simulates_as_alone(tmp_path):
    path = save_joint_twins(tmp_path / "twin.json", TWINS)
    back = load_joint_twins(path)
    assert list(back) == ["elbow", "knee", "ankle"]
    rE = 0.5 + 0.4 * np.sin(np.linspace(0, 20, 3000))
    for t in TWINS:
        b = back[t.joint]
        assert (b.measured_quantity, b.measured_unit) == (t.measured_quantity,
                                                           t.measured_unit)
        assert np.array_equal(b.simulate(rE, 0.6, 2000.0), t.simulate(rE, 0.6, 2000.0))


def test_a_one_joint_file_reads_as_one_entry(tmp_path):
    TWINS[1].save(tmp_path / "knee.json")
    data = json.loads((tmp_path / "knee.json").read_text())
    assert data["joint"] == "knee" and data["measured_unit"] == "N m"
    assert list(load_joint_twins(tmp_path / "knee.json")) == ["knee"]
    TWINS[0].save(tmp_path / "elbow.json")       # an elbow twin is written as before
    assert "joint" not in json.loads((tmp_path / "elbow.json").read_text())


def test_refusals_name_the_item(tmp_path):
    with pytest.raises(TwinFileError, match="one twin per joint"):
        joint_twins_to_dict([TWINS[1], TWINS[1]])
    data = joint_twins_to_dict(TWINS)
    del data["joints"]["knee"]["parameters"]["Kp"]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(TwinFileError, match=r"joints\.knee: parameters\.Kp is missing"):
        load_joint_twins(tmp_path / "bad.json")
    # a reader that knows one twin only refuses a multi-joint file in one line
    save_joint_twins(tmp_path / "multi.json", TWINS)
    with pytest.raises(TwinFileError, match="missing 'parameters'"):
        Twin.load(tmp_path / "multi.json")
    data = joint_twins_to_dict(TWINS)
    data["joints"]["knee"]["measured_quantity"] = "voltage"
    (tmp_path / "q.json").write_text(json.dumps(data))
    with pytest.raises(TwinFileError, match="measured_quantity 'voltage'"):
        load_joint_twins(tmp_path / "q.json")
