"""The FMU's binary: built from its sources alone, run from C without Python, free of
libpython, and held to the one definition of the twin's dynamics across randomised twins
with each effect (docs/fmu.md)."""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile

import numpy as np
import pytest

from nmsid.analysis.twin import Curve, Twin
from nmsid.export.fmu import export_fmu
from nmsid.export.fmu.fmpy_support import fmpy_input, fmpy_input_derivatives_fixed
from nmsid.export.fmu.reference import TwinStepper
from nmsid.export.fmu.variables import CURVE_CODES, FATIGUE_CODES, RECRUITMENT_CODES

fmpy = pytest.importorskip("fmpy")
from fmpy import simulate_fmu  # noqa: E402  (after the skip)

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")

FS_HZ = 1000.0
TWIN = {"format": "nmsid-twin", "format_version": 1, "participant": "P01",
        "source": [{"file": "P01.h5", "sha256": "ef" * 32}], "calibration": {},
        "sE_range": [0.3, 1.0],
        "parameters": {"Kp": {"model": "exponential", "coefficients": [0.9, 1.6]},
                       "wn_rad_s": {"model": "quadratic", "coefficients": [10.0, 40.0, -25.0]},
                       "zeta": {"model": "linear", "coefficients": [0.4, 0.3]}},
        "offset_N": {"model": "constant", "coefficients": [0.3]}, "effects": []}


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    d = tmp_path_factory.mktemp("fmu_bin")
    (d / "twin.json").write_text(json.dumps(TWIN), encoding="utf-8")
    return export_fmu(d / "twin.json", d / "P01.fmu")


def _inputs():
    t = np.arange(1200) / FS_HZ
    rE = 0.5 + 0.4 * np.sin(2 * np.pi * (1.0 + 4.0 * t) * t) * (t > 0.05)
    sE = np.linspace(0.25, 1.05, len(t))
    return rE, sE


def _cosim(path, rE, sE, start_values=None):
    with fmpy_input_derivatives_fixed():
        return simulate_fmu(str(path), fmi_type="CoSimulation", start_time=0.0,
                            stop_time=(len(rE) - 1) / FS_HZ, output_interval=1.0 / FS_HZ,
                            input=fmpy_input(rE, sE, FS_HZ), set_input_derivatives=True,
                            output=["force_N"], start_values=start_values or {})["force_N"]


def test_built_from_its_sources_alone_in_a_clean_directory(fmu, tmp_path):
    """Unzip, delete the binary, build it with the command of documentation/index.html,
    zip again: same results."""
    root = tmp_path / "unzipped"
    with zipfile.ZipFile(fmu.path) as z:
        z.extractall(root)
    shutil.rmtree(root / "binaries")
    so = root / "binaries" / "linux64" / f"{fmu.model_identifier}.so"
    so.parent.mkdir(parents=True)
    subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-std=c99", "-fvisibility=hidden",
                    "-Isources", "sources/nmsid_model.c", "sources/nmsid_twin.c", "-o",
                    str(so), "-lm"], cwd=root, check=True)
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(rebuilt, "w") as z:
        for p in sorted(root.rglob("*")):
            if p.is_file():
                z.write(p, p.relative_to(root).as_posix())
    rE, sE = _inputs()
    np.testing.assert_allclose(_cosim(rebuilt, rE, sE), _cosim(fmu.path, rE, sE), rtol=0,
                               atol=1e-12)


HARNESS = r"""
#include <stdio.h>
#include <dlfcn.h>
#include "fmi2Functions.h"
static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                   fmi2String m, ...) { fprintf(stderr, "%s: %s\n", c, m); }
int main(int argc, char **argv) {
    void *lib = dlopen(argv[1], RTLD_NOW);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    fmi2InstantiateTYPE *inst = (fmi2InstantiateTYPE *)dlsym(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)dlsym(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter =
        (fmi2EnterInitializationModeTYPE *)dlsym(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exitm =
        (fmi2ExitInitializationModeTYPE *)dlsym(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE *setr = (fmi2SetRealTYPE *)dlsym(lib, "fmi2SetReal");
    fmi2GetRealTYPE *getr = (fmi2GetRealTYPE *)dlsym(lib, "fmi2GetReal");
    fmi2DoStepTYPE *step = (fmi2DoStepTYPE *)dlsym(lib, "fmi2DoStep");
    fmi2SetRealInputDerivativesTYPE *setd =
        (fmi2SetRealInputDerivativesTYPE *)dlsym(lib, "fmi2SetRealInputDerivatives");
    fmi2Integer order[1] = {1};
    fmi2Real slope;
    fmi2CallbackFunctions cb = {logger, NULL, NULL, NULL, NULL};
    fmi2Component c = inst("h", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    fmi2ValueReference in[2] = {0, 1}, out[1] = {2};
    fmi2Real u[2] = {0.5, 0.6}, y;
    int k;
    if (!c) return 3;
    setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    enter(c); setr(c, in, 2, u); exitm(c);
    for (k = 0; k < 2000; k++) {
        u[0] = k < 100 ? 0.5 : 0.7;          /* a step of 0.2 in rE */
        setr(c, in, 2, u);
        slope = (k + 1 == 100 ? 0.2 : 0.0) / 1e-3;   /* straight line to the next sample */
        setd(c, in, 1, order, &slope);
        getr(c, out, 1, &y);
        printf("%.17g\n", y);
        if (step(c, k * 1e-3, 1e-3, fmi2True) != fmi2OK) return 4;
    }
    return 0;
}
"""


def test_a_c_harness_runs_the_binary_without_python(fmu, tmp_path):
    root = tmp_path / "u"
    with zipfile.ZipFile(fmu.path) as z:
        z.extractall(root)
    (tmp_path / "harness.c").write_text(HARNESS)
    exe = tmp_path / "harness"
    subprocess.run(["cc", "-std=c99", f"-I{root / 'sources'}", str(tmp_path / "harness.c"),
                    "-o", str(exe), "-ldl"], check=True)
    so = root / "binaries" / "linux64" / f"{fmu.model_identifier}.so"
    run = subprocess.run([str(exe), str(so), fmu.guid], capture_output=True, text=True,
                         env={"PATH": "/usr/bin:/bin"}, check=True)
    y = np.array([float(v) for v in run.stdout.split()])
    twin = Twin.from_dict(TWIN)
    kp, wn, zeta = (float(v) for v in twin.parameters_at(0.6))
    assert y[0] == pytest.approx(0.3, abs=1e-12)                 # offset, at rest
    assert y[-1] == pytest.approx(0.3 + kp * 0.2, rel=1e-6)       # settles at Kp * 0.2
    ref = twin.simulate(np.where(np.arange(2000) < 100, 0.5, 0.7), 0.6, 1000.0)
    assert np.max(np.abs(y - ref)) < 1e-6 * np.max(np.abs(ref))
    assert zeta > 0 and wn > 0


def test_binary_does_not_link_python(fmu, tmp_path):
    if shutil.which("ldd") is None:
        pytest.skip("needs ldd")
    root = tmp_path / "u"
    with zipfile.ZipFile(fmu.path) as z:
        z.extractall(root)
    so = root / "binaries" / "linux64" / f"{fmu.model_identifier}.so"
    libs = subprocess.run(["ldd", str(so)], capture_output=True, text=True, check=True).stdout
    assert "libm" in libs or "libc" in libs
    assert "python" not in libs.lower()
    syms = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True,
                          text=True).stdout if shutil.which("nm") else "fmi2DoStep"
    assert "fmi2DoStep" in syms


def _random_twin(rng, effect: str | None) -> dict:
    lo = float(rng.uniform(0.2, 0.4))
    hi = float(rng.uniform(0.8, 1.0))
    models = ["constant", "linear", "quadratic", "exponential"]
    params = {}
    for name, base in (("Kp", rng.uniform(2, 10)), ("wn_rad_s", rng.uniform(12, 40)),
                       ("zeta", rng.uniform(0.3, 1.4))):
        m = models[rng.integers(4)]
        coef = {"constant": [base], "linear": [base, base * rng.uniform(-0.3, 0.3)],
                "quadratic": [base, base * rng.uniform(-0.3, 0.3), base * rng.uniform(-0.2, 0.2)],
                "exponential": [base, rng.uniform(-0.4, 0.4)]}[m]
        params[name] = {"model": m, "coefficients": [float(c) for c in coef]}
    offset = {"model": "linear", "coefficients": [float(rng.uniform(-1, 1)),
                                                  float(rng.uniform(-0.5, 0.5))]}
    effects = {
        None: [],
        "power": [{"name": "recruitment_nonlinearity",
                   "params": {"shape": "power", "gamma": float(rng.uniform(0.5, 3))}}],
        "sigmoid": [{"name": "recruitment_nonlinearity",
                     "params": {"shape": "sigmoid", "slope": float(rng.uniform(3, 12)),
                                "midpoint": float(rng.uniform(0.3, 0.6))}}],
        "threshold_saturation": [{"name": "recruitment_nonlinearity", "params": {
            "shape": "threshold_saturation", "threshold": float(rng.uniform(0, 0.2)),
            "saturation": float(rng.uniform(0.6, 1.0))}}],
        "activation_dynamics": [{"name": "activation_dynamics",
                                 "params": {"tau_s": float(rng.uniform(0.005, 0.08))}}],
        "flexor_extensor_asymmetry": [{"name": "flexor_extensor_asymmetry", "params": {
            "wn_ratio": float(rng.uniform(0.6, 1.5)), "zeta_ratio": float(rng.uniform(0.6, 1.5))}}],
        "dead_time": [{"name": "dead_time", "params": {"L_s": float(rng.uniform(0.002, 0.06))}}],
        "fatigue": [{"name": "fatigue", "params": {
            "shape": ["exponential", "linear"][rng.integers(2)],
            "gain_loss_pct": float(rng.uniform(5, 60)), "reference_stim_s": 0.5}}],
    }[effect]
    return {**TWIN, "sE_range": [lo, hi], "parameters": params, "offset_N": offset,
            "effects": effects}


def _start_values(data: dict) -> dict:
    """The FMU's parameters for a twin (one binary runs them all)."""
    sv = {"sE_min": data["sE_range"][0], "sE_max": data["sE_range"][1]}
    for key, curve in (("Kp", data["parameters"]["Kp"]), ("wn", data["parameters"]["wn_rad_s"]),
                       ("zeta", data["parameters"]["zeta"]), ("offset", data["offset_N"])):
        sv[f"{key}_model"] = CURVE_CODES[curve["model"]]
        for i in range(3):
            sv[f"{key}_c{i}"] = (curve["coefficients"] + [0.0, 0.0])[i]
    for e in data["effects"]:
        p = e["params"]
        if e["name"] == "recruitment_nonlinearity":
            sv["recruitment_shape"] = RECRUITMENT_CODES[p["shape"]]
            vals = [p.get(k) for k in ("gamma", "slope", "midpoint", "threshold", "saturation")
                    if p.get(k) is not None]
            sv["recruitment_p1"], sv["recruitment_p2"] = (vals + [0.0])[:2]
        elif e["name"] == "dead_time":
            sv["dead_time_s"] = p["L_s"]
        elif e["name"] == "activation_dynamics":
            sv["activation_tau_s"] = p["tau_s"]
        elif e["name"] == "flexor_extensor_asymmetry":
            sv["asym_wn_ratio"], sv["asym_zeta_ratio"] = p["wn_ratio"], p["zeta_ratio"]
        elif e["name"] == "fatigue":
            sv["fatigue_shape"] = FATIGUE_CODES[p["shape"]]
            sv["fatigue_gain_loss_pct"] = p["gain_loss_pct"]
            sv["fatigue_reference_stim_s"] = p["reference_stim_s"]
    return sv


@pytest.mark.parametrize("effect", [None, "power", "sigmoid", "threshold_saturation",
                                    "activation_dynamics", "flexor_extensor_asymmetry",
                                    "dead_time", "fatigue"])
def test_binary_equals_the_python_definition_on_randomised_twins(fmu, effect):
    """The C step and the Python step (export.fmu.reference) agree on random twins, and
    without effects the Python step is `nmsid twin simulate`'s."""
    rng = np.random.default_rng(abs(hash(effect)) % 2 ** 32 if effect else 11)
    rE, sE = _inputs()
    for _ in range(1 if effect else 2):
        data = _random_twin(rng, effect)
        twin = Twin.from_dict(data)
        ref = TwinStepper(twin).simulate(rE, sE, FS_HZ, rest_lead_s=0.0)
        got = _cosim(fmu.path, rE, sE, _start_values(data))
        scale = np.max(np.abs(ref))
        assert np.max(np.abs(got - ref)) < 1e-9 * scale
        if effect is None:
            np.testing.assert_allclose(twin.simulate(rE, sE, FS_HZ), TwinStepper(
                twin).simulate(rE, sE, FS_HZ), rtol=0, atol=1e-9 * scale)
        else:   # the effect changes the force (the test would see a missing effect)
            plain = Twin.from_dict({**data, "effects": []}).simulate(rE, sE, FS_HZ)
            assert np.max(np.abs(plain - ref)) > 1e-4 * scale


def test_curve_values_are_read_from_parameters(fmu):
    twin = Twin("X", {"Kp": Curve("constant", [4.0]), "wn_rad_s": Curve("constant", [25.0]),
                      "zeta": Curve("constant", [0.6])}, (0.3, 1.0))
    rE, sE = _inputs()
    data = twin.to_dict()
    got = _cosim(fmu.path, rE, sE, _start_values(data))
    ref = twin.simulate(rE, sE, FS_HZ)
    # rest_lead_s = 0 in the FMU: equal once the first interval's ramp has died out
    np.testing.assert_allclose(got[300:], ref[300:], atol=1e-6 * np.max(np.abs(ref)))


def test_extrapolate_evaluates_the_curves_outside_the_range(fmu):
    """`extrapolate = true` is `nmsid twin simulate --extrapolate`; the default clamps."""
    rE, _ = _inputs()
    sE = np.linspace(0.15, 1.25, len(rE))
    twin = Twin.from_dict(TWIN)
    sv = {"rest_lead_s": 1.0 / FS_HZ}
    got = _cosim(fmu.path, rE, sE, {**sv, "extrapolate": True})
    ref = twin.simulate(rE, sE, FS_HZ, clip=False)
    assert np.max(np.abs(got - ref)) < 1e-9 * np.max(np.abs(ref))
    clamped = _cosim(fmu.path, rE, sE, sv)
    assert np.max(np.abs(clamped - twin.simulate(rE, sE, FS_HZ))) < 1e-9 * np.max(np.abs(ref))
    assert np.max(np.abs(clamped - got)) > 1e-3 * np.max(np.abs(ref))
