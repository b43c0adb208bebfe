"""The FMU of a torque joint's twin (docs/joints.md): units in N m, validated by FMPy, the
same torque as ``Twin.simulate``; one FMU of a participant's several joints (issue 41 item
5): inputs rE_<joint>, sE_<joint>, each joint's force or torque out, as ``nmsid twin
simulate --joint`` gives it."""

from __future__ import annotations

import json
import os
import shutil
import stat
import zipfile
from types import SimpleNamespace
from xml.etree import ElementTree

import numpy as np
import pytest

import nmsid
from nmsid.analysis.joint_twins import joint_twins_to_dict, load_joint_twins, save_joint_twins
from nmsid.analysis.twin import Twin
from nmsid.cli import main
from nmsid.export.errors import FmuExportError
from nmsid.export.fmu import export_fmu
from nmsid.export.fmu.fmpy_support import (
    fmpy_input,
    fmpy_input_derivatives_fixed,
    fmpy_joint_input,
    on_output_grid,
)
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


# -- one FMU of several joints -------------------------------------------------------------

JOINTS = ("elbow", "knee", "ankle")
OUTPUT = {"elbow": "force_N_elbow", "knee": "torque_Nm_knee", "ankle": "torque_Nm_ankle"}


@pytest.fixture(scope="module")
def leg(tmp_path_factory):
    """LEG1's twin of three joints (the template participants' twins, as the test above
    builds each), exported by `nmsid export fmu`."""
    d = tmp_path_factory.mktemp("fmu_leg")
    twins = [Twin.from_dict(_joint_twin(j)) for j in JOINTS]
    twins[2].effects = [{"name": "activation_dynamics", "params": {"tau_s": 0.02}}]
    path = save_joint_twins(d / "LEG1.json", twins)
    assert main(["export", "fmu", str(path), "--out", str(d / "LEG1.fmu")]) == 0
    return SimpleNamespace(path=path, fmu=d / "LEG1.fmu", dir=d, twins=load_joint_twins(path))


def _cli_inputs(leg) -> dict:
    """Each joint's input and force/torque as `nmsid twin simulate --joint` writes them:
    a different input per joint (the elbow's chirp at sE 0.6, the knee's sine on an sE
    ramp from a CSV, the ankle's chirp at sE 0.9), 4000 samples at 2 kHz each."""
    fs, n = 2000.0, 4000
    t = np.arange(n) / fs
    knee_in = leg.dir / "knee_in.csv"
    knee_in.write_text("t_s,rE,sE\n" + "".join(
        f"{a:.6f},{r:.9g},{s:.9g}\n" for a, r, s in zip(
            t, 0.5 + 0.35 * np.sin(2 * np.pi * 1.5 * t), np.linspace(0.25, 1.1, n),
            strict=True)), encoding="utf-8")
    args = {"elbow": ["--rE-chirp", "--sE", "0.6", "--steady-s", "0.5", "--chirp-s", "1.5"],
            "knee": ["--input", str(knee_in)],
            "ankle": ["--rE-chirp", "--sE", "0.9", "--steady-s", "0.2", "--chirp-s", "1.8",
                      "--f0-Hz", "0.5", "--f1-Hz", "6"]}
    out = {}
    for j in JOINTS:
        csv = leg.dir / f"{j}.csv"
        assert main(["twin", "simulate", str(leg.path), "--joint", j, *args[j], "--out",
                     str(csv), "--force"]) == 0
        out[j] = np.loadtxt(csv, delimiter=",", skiprows=1)
        assert len(out[j]) == n
    return out


def test_a_multi_joint_twin_is_one_fmu_that_fmpy_validates(leg):
    assert validate_fmu(str(leg.fmu)) == []
    md = read_model_description(str(leg.fmu), validate=True)
    var = {v.name: v for v in md.modelVariables}
    ins = sorted(v.name for v in md.modelVariables if v.causality == "input")
    assert ins == sorted(f"{q}_{j}" for j in JOINTS for q in ("rE", "sE"))
    outs = {v.name for v in md.modelVariables if v.causality == "output"}
    assert outs == {f"{o}_{j}" for j in JOINTS for o in ("Kp", "wn_rad_s", "zeta")} | set(
        OUTPUT.values())
    # units declared per joint: the elbow's force in N, a leg joint's torque in N m
    assert var["force_N_elbow"].unit == "N" and var["Kp_elbow"].unit == "N"
    for j in ("knee", "ankle"):
        assert var[OUTPUT[j]].unit == "N.m" and var[f"Kp_{j}"].unit == "N.m"
        assert f"{j} joint torque" in var[OUTPUT[j]].description
    assert {u.name for u in md.unitDefinitions} >= {"N", "N.m", "rad/s"}
    # each joint's parameters hold its own twin's values
    for j in JOINTS:
        kp = leg.twins[j].parameters["Kp"]
        assert float(var[f"Kp_c0_{j}"].start) == kp.coefficients[0]
    assert float(var["activation_tau_s_ankle"].start) == 0.02
    assert float(var["activation_tau_s_knee"].start) == 0.0
    # 7 states per joint, in joint order (the order of the Derivatives)
    assert [d.variable.name for d in md.derivatives][7::7] == [
        "der(a_ext_knee)", "der(a_ext_ankle)"]
    with zipfile.ZipFile(leg.fmu) as z:
        assert z.read("resources/twin.json") == leg.path.read_bytes()
        tool = ElementTree.fromstring(z.read("modelDescription.xml")).find(
            "VendorAnnotations/Tool[@name='nmsid']/Twin")
    assert [(e.get("name"), e.get("unit")) for e in tool.findall("Joint")] == [
        ("elbow", "N"), ("knee", "N m"), ("ankle", "N m")]
    assert tool.find("Joint[@name='ankle']/Effect").get("name") == "activation_dynamics"


def test_the_multi_joint_fmu_matches_twin_simulate_per_joint(leg):
    """The done-when of issue 41: each joint's output of the one FMU, co-simulated in FMPy
    with every joint's own input at once, within 1e-6 of the peak of `nmsid twin simulate
    --joint` (today's single-joint FMU test's bound, test_fmu.py)."""
    cli = _cli_inputs(leg)
    with fmpy_input_derivatives_fixed():
        res = simulate_fmu(str(leg.fmu), fmi_type="CoSimulation", start_time=0.0,
                           stop_time=(4000 - 1) / 2000.0, output_interval=1.0 / 2000.0,
                           input=fmpy_joint_input({j: (cli[j][:, 1], cli[j][:, 2])
                                                   for j in JOINTS}, 2000.0),
                           set_input_derivatives=True, output=list(OUTPUT.values()))
    for j in JOINTS:
        ref = cli[j][:, 3]
        err = np.max(np.abs(res[OUTPUT[j]] - ref)) / np.max(np.abs(ref))
        assert err < 1e-6, (j, err)
    # the joints' outputs differ (a mix-up of joints could not pass the bound above)
    assert np.max(np.abs(res[OUTPUT["knee"]] - res[OUTPUT["ankle"]])) > 1.0


def test_the_multi_joint_fmu_in_model_exchange(leg):
    """FMPy's own solver on the joints' 21 states, within 1e-3 as the one-joint FMU."""
    fs, n, sub = 1000.0, 500, 20
    t = np.arange(n) / fs
    ins = {"elbow": (0.5 + 0.4 * np.sin(2 * np.pi * 3 * t), 0.6),
           "knee": (0.5 + 0.3 * np.sin(2 * np.pi * 5 * t), np.linspace(0.3, 1.0, n)),
           "ankle": (0.5 - 0.3 * np.sin(2 * np.pi * 2 * t), 0.8)}
    res = simulate_fmu(str(leg.fmu), fmi_type="ModelExchange", start_time=0.0,
                       stop_time=(n - 1) / fs, output_interval=1.0 / fs / sub,
                       input=fmpy_joint_input(ins, fs, lead=0.0),
                       output=list(OUTPUT.values()), relative_tolerance=1e-8)
    for j in JOINTS:
        ref = nmsid.simulate_twin(leg.path, ins[j][0], ins[j][1], fs, joint=j)
        f = on_output_grid(res, OUTPUT[j], sub)
        assert np.max(np.abs(f - ref)) / np.max(np.abs(ref)) < 1e-3, j


def test_a_joint_name_no_fmu_variable_can_carry_is_refused(tmp_path):
    data = joint_twins_to_dict([Twin.from_dict(_joint_twin(j)) for j in ("elbow", "knee")])
    data["joints"]["left knee"] = data["joints"].pop("knee")
    data["joints"]["left knee"]["joint"] = "left knee"
    (tmp_path / "t.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(FmuExportError, match=r"joint name 'left knee' cannot name FMU "
                                             r"variables"):
        export_fmu(tmp_path / "t.json", tmp_path / "t.fmu", binary=False)
    data["joints"]["knee"] = data["joints"].pop("left knee")
    data["joints"]["knee"]["joint"] = "knee"
    data["joints"]["knee"]["effects"] = [
        {"name": "baseline_drift", "params": {"amplitude_N": 0.1, "corner_Hz": 0.05}}]
    (tmp_path / "t.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(FmuExportError, match=r"joints\.knee: effect baseline_drift is not "
                                             r"in the FMU"):
        export_fmu(tmp_path / "t.json", tmp_path / "t.fmu", binary=False)
    assert not (tmp_path / "t.fmu").exists()


@pytest.mark.skipif(os.name == "nt", reason="POSIX permission bits")
def test_export_fmu_gives_a_new_files_usual_mode(leg, tmp_path):
    """Issue 39: `nmsid export fmu` writes 0666 less the umask, not mkstemp's 0600."""
    old = os.umask(0o002)
    try:
        assert main(["export", "fmu", str(leg.path), "--out", str(tmp_path / "m.fmu"),
                     "--sources-only"]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "m.fmu").stat().st_mode) == 0o664
