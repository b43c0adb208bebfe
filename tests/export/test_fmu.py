"""The twin as an FMU, checked in FMPy: validation, metadata, co-simulation and model
exchange against ``nmsid twin simulate``, refusals (docs/fmu.md)."""

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

from nmsid.analysis.gap.twin_out import twin_dict
from nmsid.analysis.twin import Twin, file_sha256
from nmsid.cli import main
from nmsid.cli.twin_export_command import run_twin_export
from nmsid.export.errors import FmuExportError
from nmsid.export.fmu import export_fmu
from nmsid.export.fmu.fmpy_support import fmpy_input, fmpy_input_derivatives_fixed, on_output_grid
from nmsid.export.fmu.reference import TwinStepper
from nmsid.sim_backends.participant import default_participant

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402  (after the skip)
from fmpy.validation import validate_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")

FS_HZ = 1000.0
SE_LEVELS = (0.2, 0.35, 0.6, 0.85, 1.2)       # includes one below and one above the range


def chirp(fs_Hz, steady_s, chirp_s, f0_Hz=1.0, f1_Hz=10.0):
    """As ``nmsid twin simulate --rE-chirp``."""
    n = int(round((steady_s + chirp_s) * fs_Hz))
    t = np.arange(n) / fs_Hz
    tc = np.clip(t - steady_s, 0.0, None)
    k = f1_Hz / f0_Hz
    phi = 2 * np.pi * f0_Hz * chirp_s / np.log(k) * (k ** (tc / chirp_s) - 1)
    return np.where(t < steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The simulator's default participant as a twin (what `make demo` identifies), with a
    linear offset so that the offset's sE dependence is exercised too."""
    d = tmp_path_factory.mktemp("fmu_demo")
    data = default_participant().to_twin()
    data["participant"] = "DEMO"
    data["source"] = [{"file": "DEMO.h5", "sha256": "ab" * 32}]
    data["offset_N"] = {"model": "linear", "coefficients": [0.1, 0.4]}
    twin_path = d / "twin.json"
    twin_path.write_text(json.dumps(data), encoding="utf-8")
    result = export_fmu(twin_path, d / "DEMO.fmu")
    return SimpleNamespace(twin=Twin.load(twin_path), twin_path=twin_path, fmu=result.path,
                           result=result, dir=d)


@pytest.fixture(scope="module")
def augmented(tmp_path_factory):
    """A twin as `nmsid gap` writes it (analysis.gap.twin_out.twin_dict) with every effect
    the FMU models."""
    d = tmp_path_factory.mktemp("fmu_aug")
    sE = np.linspace(0.3, 1.0, 8)
    cal = SimpleNamespace(Iemin_mA=2.0, Iemax_mA=9.5, Ifmin_mA=1.5, Ifmax_mA=8.0, Fmin_N=0.5,
                          Fmax_N=5.0)
    effects = [
        {"name": "recruitment_nonlinearity", "params": {"shape": "sigmoid", "slope": 7.0,
                                                        "midpoint": 0.45}},
        {"name": "activation_dynamics", "params": {"tau_s": 0.03}},
        {"name": "flexor_extensor_asymmetry", "params": {"wn_ratio": 0.8, "zeta_ratio": 1.3}},
        {"name": "dead_time", "params": {"L_s": 0.0237}},
        {"name": "fatigue", "params": {"shape": "exponential", "gain_loss_pct": 20.0,
                                       "reference_stim_s": 675.0}},
    ]
    data = twin_dict(participant="P07", source=[{"file": "P07.h5", "sha256": "cd" * 32}],
                     calibration=cal, sE_levels=sE, Kp=2.0 + 6.0 * sE,
                     wn_rad_s=18.0 + 20.0 * sE, zeta=0.5 + 0.4 * sE, effects=effects)
    twin_path = d / "twin.json"
    twin_path.write_text(json.dumps(data), encoding="utf-8")
    return SimpleNamespace(twin=Twin.load(twin_path), twin_path=twin_path,
                           fmu=export_fmu(twin_path, d / "P07.fmu").path)


def _cosim(fmu, rE, sE, fs_Hz, **kw):
    with fmpy_input_derivatives_fixed():
        res = simulate_fmu(str(fmu), fmi_type="CoSimulation", start_time=0.0,
                           stop_time=(len(rE) - 1) / fs_Hz, output_interval=1.0 / fs_Hz,
                           input=fmpy_input(rE, sE, fs_Hz), set_input_derivatives=True,
                           output=["force_N", "Kp", "wn_rad_s", "zeta"], **kw)
    assert len(res) == len(rE)
    return res


# -- the model description --------------------------------------------------------------

def test_fmpy_validation_passes_and_variables_are_documented(demo):
    assert validate_fmu(str(demo.fmu)) == []
    md = read_model_description(str(demo.fmu), validate=True)
    assert md.fmiVersion == "2.0"
    assert md.modelExchange is not None and md.coSimulation is not None
    assert md.coSimulation.canInterpolateInputs
    by_name = {v.name: v for v in md.modelVariables}
    assert by_name["rE"].causality == by_name["sE"].causality == "input"
    assert [by_name[n].causality for n in ("force_N", "Kp", "wn_rad_s", "zeta")] == ["output"] * 4
    assert by_name["force_N"].unit == "N" and by_name["wn_rad_s"].unit == "rad/s"
    for v in md.modelVariables:
        assert len(v.description) > 10, v.name
        if v.type == "Real":
            assert v.unit is not None, v.name
    # every curve coefficient and the offset are parameters holding the twin's values
    kp = demo.twin.parameters["Kp"]
    assert float(by_name["Kp_c0"].start) == kp.coefficients[0]
    assert float(by_name["offset_c1"].start) == 0.4
    assert by_name["Kp_model"].start == {"linear": "1", "quadratic": "2", "exponential": "3",
                                         "constant": "0"}[kp.model]
    # the sE rule is stated
    assert "clamped to the tested range" in by_name["sE"].description
    assert float(by_name["sE_min"].start) == demo.twin.sE_range[0]


def test_metadata_names_participant_sources_and_version(demo):
    with zipfile.ZipFile(demo.fmu) as z:
        names = set(z.namelist())
        xml = z.read("modelDescription.xml")
        assert z.read("resources/twin.json") == demo.twin_path.read_bytes()
    assert {"sources/nmsid_twin.c", "sources/nmsid_model.c", "sources/twin_data.h",
            "sources/fmi2Functions.h",
            f"binaries/linux64/{demo.result.model_identifier}.so"} <= names
    root = ElementTree.fromstring(xml)
    tool = root.find("VendorAnnotations/Tool[@name='nmsid']/Twin")
    assert tool.get("participant") == "DEMO"
    assert tool.get("twinFileSha256") == file_sha256(demo.twin_path)
    assert tool.find("Source").get("sha256") == "ab" * 32
    assert tool.get("nmsidVersion") == root.get("generationTool").split()[-1]
    assert root.get("generationTool").startswith("nmsid ")


# -- co-simulation: the sampling step reproduces `nmsid twin simulate` --------------------

def test_cosim_matches_twin_simulate_over_chirps_and_ramp(demo):
    rE = chirp(FS_HZ, 0.2, 2.0)
    worst = 0.0
    cases = [np.full(len(rE), s) for s in SE_LEVELS] + [np.linspace(0.2, 1.2, len(rE))]
    for sE in cases:
        ref = demo.twin.simulate(rE, sE, FS_HZ)
        res = _cosim(demo.fmu, rE, sE, FS_HZ)
        err = np.max(np.abs(res["force_N"] - ref)) / np.max(np.abs(ref))
        worst = max(worst, err)
        s_c = np.clip(sE, *demo.twin.sE_range)
        np.testing.assert_allclose(res["Kp"], demo.twin.parameters["Kp"](s_c), rtol=1e-9)
    assert worst < 1e-6, worst


def test_cosim_matches_the_cli_on_its_own_chirp(demo, tmp_path):
    out = tmp_path / "force.csv"
    assert main(["twin", "simulate", str(demo.twin_path), "--rE-chirp", "--sE", "0.6",
                 "--steady-s", "1.0", "--chirp-s", "4.0", "--f0-Hz", "1.0", "--f1-Hz", "10.0",
                 "--out", str(out)]) == 0
    cli = np.loadtxt(out, delimiter=",", skiprows=1)
    res = _cosim(demo.fmu, cli[:, 1], cli[:, 2], 2000.0)
    err = np.max(np.abs(res["force_N"] - cli[:, 3])) / np.max(np.abs(cli[:, 3]))
    assert err < 1e-6, err


def test_cosim_matches_the_cli_on_an_augmented_twin(augmented, tmp_path):
    """`nmsid twin simulate` runs a gap twin's effects with the FMU's definition of them."""
    out = tmp_path / "force.csv"
    assert main(["twin", "simulate", str(augmented.twin_path), "--rE-chirp", "--sE", "0.6",
                 "--steady-s", "1.0", "--chirp-s", "3.0", "--out", str(out)]) == 0
    cli = np.loadtxt(out, delimiter=",", skiprows=1)
    res = _cosim(augmented.fmu, cli[:, 1], cli[:, 2], 2000.0)
    err = np.max(np.abs(res["force_N"] - cli[:, 3])) / np.max(np.abs(cli[:, 3]))
    assert err < 1e-6, err
    curves = tmp_path / "curves.csv"
    assert main(["twin", "simulate", str(augmented.twin_path), "--rE-chirp", "--sE", "0.6",
                 "--steady-s", "1.0", "--chirp-s", "3.0", "--without-effects",
                 "--out", str(curves)]) == 0
    plain = np.loadtxt(curves, delimiter=",", skiprows=1)[:, 3]
    assert np.max(np.abs(plain - cli[:, 3])) > 0.05 * np.max(np.abs(cli[:, 3]))


def test_twin_simulate_refuses_an_effect_it_cannot_simulate(augmented, tmp_path, capsys):
    data = json.loads(augmented.twin_path.read_text())
    data["effects"].append({"name": "baseline_drift",
                            "params": {"amplitude_N": 0.2, "corner_Hz": 0.05, "seed": 1}})
    twin = tmp_path / "drift.json"
    twin.write_text(json.dumps(data), encoding="utf-8")
    assert main(["twin", "simulate", str(twin), "--rE-chirp", "--sE", "0.6",
                 "--out", str(tmp_path / "f.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "baseline_drift" in err[0] and "--without-effects" in err[0]


def test_rest_lead_reproduces_a_record_that_starts_away_from_rest(demo):
    rng = np.random.default_rng(3)
    rE = 0.5 + 0.3 * np.sin(np.arange(400) / 25.0) + 0.05 * rng.standard_normal(400)
    ref = demo.twin.simulate(rE, 0.7, FS_HZ)
    res = _cosim(demo.fmu, rE, 0.7, FS_HZ, start_values={"rest_lead_s": 1.0 / FS_HZ})
    assert np.max(np.abs(res["force_N"] - ref)) / np.max(np.abs(ref)) < 1e-6
    held = _cosim(demo.fmu, rE, 0.7, FS_HZ)          # default: at rest at the start
    assert held["force_N"][0] == pytest.approx(demo.twin.offset_N(0.7), abs=1e-12)


# -- model exchange under FMPy's own solver ------------------------------------------------

@pytest.mark.parametrize("sE", ["ramp"])
def test_model_exchange_within_1e3(demo, sE):
    rE = chirp(FS_HZ, 0.05, 0.5)
    s = np.linspace(0.25, 1.1, len(rE)) if sE == "ramp" else np.full(len(rE), sE)
    ref = demo.twin.simulate(rE, s, FS_HZ)
    sub = 20          # FMPy holds inputs between output points: sample them finer
    res = simulate_fmu(str(demo.fmu), fmi_type="ModelExchange", start_time=0.0,
                       stop_time=(len(rE) - 1) / FS_HZ, output_interval=1.0 / FS_HZ / sub,
                       input=fmpy_input(rE, s, FS_HZ, lead=0.0), output=["force_N"],
                       relative_tolerance=1e-8)
    f = on_output_grid(res, "force_N", sub)
    assert len(f) == len(ref)
    assert np.max(np.abs(f - ref)) / np.max(np.abs(ref)) < 1e-3


# -- the augmented twin -------------------------------------------------------------------

def test_augmented_twin_validates_and_matches_its_definition(augmented):
    assert validate_fmu(str(augmented.fmu)) == []
    rE = chirp(FS_HZ, 0.1, 1.0)
    stepper = TwinStepper(augmented.twin)
    worst = 0.0
    for sE in [np.full(len(rE), s) for s in SE_LEVELS] + [np.linspace(0.2, 1.2, len(rE))]:
        ref = stepper.simulate(rE, sE, FS_HZ, rest_lead_s=0.0)
        res = _cosim(augmented.fmu, rE, sE, FS_HZ)
        worst = max(worst, np.max(np.abs(res["force_N"] - ref)) / np.max(np.abs(ref)))
    assert worst < 1e-6, worst
    # the effects matter: without them the force differs by far more than that
    plain = Twin.from_dict({**augmented.twin.to_dict(), "effects": []})
    nominal = plain.simulate(rE, 0.6, FS_HZ)
    assert np.max(np.abs(nominal - stepper.simulate(rE, 0.6, FS_HZ))) > 0.05 * np.max(
        np.abs(nominal))


def test_augmented_twin_in_model_exchange(augmented):
    """Model exchange with every effect (the dead time from the history of the inputs the
    importer set) within 1e-3 of the co-simulation definition."""
    rE = chirp(FS_HZ, 0.05, 0.5)
    sE = np.linspace(0.3, 0.9, len(rE))
    ref = TwinStepper(augmented.twin).simulate(rE, sE, FS_HZ, rest_lead_s=0.0)
    sub = 20
    res = simulate_fmu(str(augmented.fmu), fmi_type="ModelExchange", start_time=0.0,
                       stop_time=(len(rE) - 1) / FS_HZ, output_interval=1.0 / FS_HZ / sub,
                       input=fmpy_input(rE, sE, FS_HZ, lead=0.0), output=["force_N"],
                       relative_tolerance=1e-8)
    f = on_output_grid(res, "force_N", sub)
    assert np.max(np.abs(f - ref)) / np.max(np.abs(ref)) < 1e-3


# -- refusals -------------------------------------------------------------------------------

@pytest.mark.parametrize("effect", [
    {"name": "baseline_drift", "params": {"amplitude_N": 0.1, "corner_Hz": 0.05}}])
def test_effects_the_fmu_does_not_model_are_refused_by_name(demo, tmp_path, effect):
    data = json.loads(demo.twin_path.read_text())
    data["effects"] = [effect]
    p = tmp_path / "t.json"
    p.write_text(json.dumps(data))
    with pytest.raises(FmuExportError) as info:
        export_fmu(p, tmp_path / "x.fmu")
    msg = str(info.value)
    assert f"effect {effect['name']} is not in the FMU" in msg and "\n" not in msg
    assert not (tmp_path / "x.fmu").exists()


def test_muscle_form_is_refused_by_name(demo, tmp_path):
    data = json.loads(demo.twin_path.read_text())
    data["muscle"] = {"model": "hill"}
    p = tmp_path / "t.json"
    p.write_text(json.dumps(data))
    with pytest.raises(FmuExportError, match=r"item\(s\) \['muscle'\]"):
        export_fmu(p, tmp_path / "x.fmu")


def test_cli_refuses_an_existing_out_unless_forced(demo, tmp_path, capsys):
    out = tmp_path / "P.fmu"
    out.write_bytes(b"user's file")
    args = SimpleNamespace(twin=str(demo.twin_path), fmu=True, out=str(out), force=False,
                           extrapolate=False, sources_only=False)
    with pytest.raises(FmuExportError, match="already exists"):
        run_twin_export(args)
    assert out.read_bytes() == b"user's file"
    args.force = True
    assert run_twin_export(args) == 0
    assert zipfile.is_zipfile(out)
    assert "co-simulation + model exchange" in capsys.readouterr().out


def test_sources_only_has_no_binary(demo, tmp_path):
    result = export_fmu(demo.twin_path, tmp_path / "src.fmu", binary=False)
    assert result.platform is None
    with zipfile.ZipFile(result.path) as z:
        names = z.namelist()
    assert "sources/nmsid_model.c" in names
    assert not [n for n in names if n.startswith("binaries/")]
    assert [p.name for p in tmp_path.iterdir()] == ["src.fmu"]      # no temporary left


@pytest.mark.skipif(os.name == "nt", reason="POSIX permission bits")
def test_the_fmu_has_a_new_files_usual_mode(demo, tmp_path):
    """Issue 39: the .fmu was written 0600 (mkstemp's mode): 0666 less the umask now."""
    old = os.umask(0o027)
    try:
        result = export_fmu(demo.twin_path, tmp_path / "m.fmu", binary=False)
    finally:
        os.umask(old)
    assert stat.S_IMODE(result.path.stat().st_mode) == 0o640
