"""A participant's twin of several joints in one file (analysis/joint_twins.py)."""

import json

import numpy as np
import pytest

import nmsid
from nmsid.analysis.errors import TwinFileError, TwinInputError
from nmsid.analysis.joint_twins import (
    joint_twin,
    joint_twins_to_dict,
    load_joint_twins,
    save_joint_twins,
)
from nmsid.analysis.twin import Curve, Twin
from nmsid.cli import main


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


# -- `nmsid twin simulate --joint` and simulate_twin(..., joint=) (issue 41 item 5) --------

def _simulate(twin, out, *extra):
    return main(["twin", "simulate", str(twin), "--rE-chirp", "--sE", "0.6", "--steady-s",
                 "0.2", "--chirp-s", "0.8", "--out", str(out), *extra])


def test_twin_simulate_runs_each_joint_of_a_multi_joint_file(tmp_path, capsys):
    path = save_joint_twins(tmp_path / "P01.json", TWINS)
    outs = {}
    for t in TWINS:
        out = tmp_path / f"{t.joint}.csv"
        assert _simulate(path, out, "--joint", t.joint) == 0
        header = out.read_text().splitlines()[0]
        # a torque joint's column and summary say torque in N m, the elbow's force in N
        assert header == ("t_s,rE,sE,force_N" if t.joint == "elbow" else "t_s,rE,sE,torque_Nm")
        said = capsys.readouterr().out
        assert (f"{t.joint} torque" in said and "N m)" in said) if t.joint != "elbow" \
            else "(force " in said
        cols = np.loadtxt(out, delimiter=",", skiprows=1)
        ref = t.simulate(cols[:, 1], cols[:, 2], 2000.0)
        np.testing.assert_allclose(cols[:, 3], ref, rtol=1e-7, atol=1e-9)
        outs[t.joint] = cols[:, 3]
    # each joint runs its own twin: three different outputs for the same input
    assert np.max(np.abs(outs["knee"] - outs["ankle"])) > 1.0
    assert np.max(np.abs(outs["knee"] - outs["elbow"])) > 1.0


def test_twin_simulate_refuses_a_joint_the_file_lacks_in_one_line(tmp_path, capsys):
    path = save_joint_twins(tmp_path / "P01.json", TWINS)
    out = tmp_path / "f.csv"
    assert _simulate(path, out, "--joint", "hip") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "no twin of joint 'hip'" in err[0] and "it holds elbow, knee, ankle" in err[0]
    # several joints and none named: which one is not guessed
    assert _simulate(path, out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "elbow, knee, ankle" in err[0] and "--joint NAME" in err[0]
    assert not out.exists()


def test_a_one_joint_twin_simulates_as_before_with_or_without_joint(tmp_path, capsys):
    TWINS[0].save(tmp_path / "elbow.json")          # no joint item: the elbow's
    plain, named = tmp_path / "plain.csv", tmp_path / "named.csv"
    assert _simulate(tmp_path / "elbow.json", plain) == 0
    assert _simulate(tmp_path / "elbow.json", named, "--joint", "elbow") == 0
    assert plain.read_bytes() == named.read_bytes()
    assert plain.read_text().startswith("t_s,rE,sE,force_N\n")
    capsys.readouterr()
    assert _simulate(tmp_path / "elbow.json", tmp_path / "k.csv", "--joint", "knee") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no twin of joint 'knee'; it holds elbow" in err[0]


def test_simulate_twin_api_takes_a_joint(tmp_path):
    path = save_joint_twins(tmp_path / "P01.json", TWINS)
    rE = 0.5 + 0.3 * np.sin(np.linspace(0, 12, 1500))
    for t in TWINS:
        got = nmsid.simulate_twin(path, rE, 0.7, 1000.0, joint=t.joint)
        np.testing.assert_array_equal(got, t.simulate(rE, 0.7, 1000.0))
        assert nmsid.load_twin(path, t.joint).joint == t.joint
    with pytest.raises(TwinInputError, match=r"joint 'hip'; it holds elbow, knee, ankle"):
        nmsid.simulate_twin(path, rE, 0.7, 1000.0, joint="hip")
    with pytest.raises(TwinInputError, match=r"joints elbow, knee, ankle: say which one "
                                             r"\(joint=NAME\)"):
        nmsid.simulate_twin(path, rE, 0.7, 1000.0)
    with pytest.raises(TwinInputError, match="the knee's, not the ankle's"):
        nmsid.simulate_twin(TWINS[1], rE, 0.7, 1000.0, joint="ankle")
    # one twin, as before: no joint needed, and its own joint accepted
    TWINS[1].save(tmp_path / "knee.json")
    np.testing.assert_array_equal(nmsid.simulate_twin(tmp_path / "knee.json", rE, 0.7, 1000.0),
                                  joint_twin(tmp_path / "knee.json", "knee")
                                  .simulate(rE, 0.7, 1000.0))
