"""The FMU of a torque joint's twin (docs/joints.md): units in N m, validated by FMPy, the
same torque as ``Twin.simulate``; one FMU per joint of a multi-joint twin file."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from nmsid.analysis.joint_twins import load_joint_twins, save_joint_twins
from nmsid.analysis.twin import Twin
from nmsid.export.fmu import export_fmu
from nmsid.export.fmu.fmpy_support import fmpy_input, fmpy_input_derivatives_fixed
from nmsid.sim_backends.joint_participants import template_participant

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402  (after the skip)
from fmpy.validation import validate_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")
FS_HZ = 1000.0


def _joint_twin(joint: str) -> dict:
    data = template_participant(joint).to_twin()
    data.update(participant="LEG1", source=[{"file": "LEG1.h5", "sha256": "ab" * 32}])
    if joint != "elbow":
        data.update(joint=joint, measured_quantity="torque", measured_unit="N m")
    return data


@pytest.mark.parametrize("joint", ["knee", "ankle"])
def test_torque_twin_fmu_validates_in_n_m_and_matches_the_twin(tmp_path, joint):
    path = tmp_path / "twin.json"
    path.write_text(json.dumps(_joint_twin(joint)), encoding="utf-8")
    fmu = export_fmu(path, tmp_path / f"{joint}.fmu").path
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu), validate=True)
    var = {v.name: v for v in md.modelVariables}
    assert var["force_N"].unit == "N.m" and f"{joint} joint torque" in var["force_N"].description
    assert var["Kp"].unit == "N.m" and var["wn_rad_s"].unit == "rad/s"
    units = {u.name: u for u in md.unitDefinitions}
    assert units["N.m"].baseUnit.m == 2 and units["N.m"].baseUnit.kg == 1
    twin = Twin.load(path)
    n = int(2.0 * FS_HZ)
    rE = 0.5 + 0.4 * np.sin(2 * np.pi * 0.4 * np.arange(n) / FS_HZ)
    ref = twin.simulate(rE, 0.7, FS_HZ)
    with fmpy_input_derivatives_fixed():
        res = simulate_fmu(str(fmu), fmi_type="CoSimulation", start_time=0.0,
                           stop_time=(n - 1) / FS_HZ, output_interval=1.0 / FS_HZ,
                           input=fmpy_input(rE, 0.7, FS_HZ), set_input_derivatives=True,
                           output=["force_N"], start_values={"rest_lead_s": 1.0 / FS_HZ})
    assert np.max(np.abs(res["force_N"] - ref)) / np.max(np.abs(ref)) < 1e-6
    assert np.max(np.abs(ref)) > 6.0   # a leg's torque in N m (the elbow template: ~2 N)


def test_one_fmu_per_joint_of_a_multi_joint_twin(tmp_path):
    twins = []
    for joint in ("elbow", "knee", "ankle"):
        p = tmp_path / f"{joint}.json"
        p.write_text(json.dumps(_joint_twin(joint)), encoding="utf-8")
        twins.append(Twin.load(p))
    both = save_joint_twins(tmp_path / "LEG1.json", twins)
    for joint, twin in load_joint_twins(both).items():
        one = tmp_path / f"one_{joint}.json"
        twin.save(one)          # each joint's twin as its own file, exported on its own
        md = read_model_description(str(export_fmu(one, tmp_path / f"{joint}.fmu",
                                                   binary=False).path), validate=False)
        unit = {v.name: v.unit for v in md.modelVariables}["force_N"]
        assert unit == ("N" if joint == "elbow" else "N.m")
