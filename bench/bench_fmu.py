"""``nmsid twin export --fmu``: export time and agreement of the FMU with ``twin simulate``.

1. Export time of a 15-level twin (curves fitted over the paper's 15 sE levels of the
   simulator's default participant, as `nmsid gap`/`identify` write them), compilation
   included, median of 3; baseline: `twin simulate`'s time for the paper's chirp (5 s
   steady + 10 s chirp at 2000 Hz) at one sE, in the same process.
2. Co-simulation in FMPy at the sampling step (input derivatives set): worst difference
   from `twin simulate` in % of the peak force over the paper's chirp at five sE levels
   (two of them outside the tested range) and an sE ramp; FMPy's time against
   `twin simulate`'s for the same input.
3. Model exchange under FMPy's own solver (CVode, rtol 1e-8): FMPy sets inputs only at
   output points and holds them in between, so the difference falls with the output
   interval; worst over the five levels and the ramp with the output at the sampling step,
   and for the ramp at a tenth of it (shorter chirp: 0.5 s + 2 s).
4. One FMU of several joints (issue 41): a participant's twin of the elbow, the knee and the
   ankle (the template participants' twins, docs/joints.md) in one file, exported as one
   FMU: its export time (median of 3) beside the fairest baseline, the three joints
   exported as three one-joint FMUs; co-simulated in FMPy over the paper's chirp with a
   different sE per joint at once (elbow 0.6, knee a ramp 0.3-1.0, ankle 0.9), the worst
   difference per joint from `twin simulate --joint` (Twin.simulate of that joint) in % of
   its peak, and FMPy's time beside the three one-joint FMUs run one after the other.

    python bench/bench_fmu.py
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fmpy import simulate_fmu  # noqa: E402

from nmsid.analysis.design.candidates import PAPER_LEVELS  # noqa: E402
from nmsid.analysis.gap.twin_out import twin_dict  # noqa: E402
from nmsid.analysis.joint_twins import load_joint_twins, save_joint_twins  # noqa: E402
from nmsid.analysis.twin import Twin  # noqa: E402
from nmsid.export.fmu import export_fmu  # noqa: E402
from nmsid.export.fmu.fmpy_support import (  # noqa: E402
    fmpy_input,
    fmpy_input_derivatives_fixed,
    fmpy_joint_input,
    on_output_grid,
)
from nmsid.sim_backends.joint_participants import template_participant  # noqa: E402
from nmsid.sim_backends.participant import default_participant  # noqa: E402

FS_HZ = 2000.0
SE_LEVELS = (0.2, 0.4, 0.6, 0.8, 1.2)


def chirp(fs_Hz, steady_s, chirp_s, f0_Hz=1.0, f1_Hz=10.0):
    """As ``nmsid twin simulate --rE-chirp``."""
    n = int(round((steady_s + chirp_s) * fs_Hz))
    t = np.arange(n) / fs_Hz
    tc = np.clip(t - steady_s, 0.0, None)
    k = f1_Hz / f0_Hz
    phi = 2 * np.pi * f0_Hz * chirp_s / np.log(k) * (k ** (tc / chirp_s) - 1)
    return np.where(t < steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))


def fifteen_level_twin(path: Path) -> Twin:
    p = default_participant()
    sE = np.asarray(PAPER_LEVELS, float)
    truth = [p.true_parameters(s) for s in sE]
    cal = SimpleNamespace(**p.to_twin()["calibration"])
    data = twin_dict(participant="P15", source=[{"file": "P15.h5", "sha256": "0" * 64}],
                     calibration=cal, sE_levels=sE, Kp=[t.Kp for t in truth],
                     wn_rad_s=[t.wn_rad_s for t in truth], zeta=[t.zeta for t in truth],
                     effects=[])
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    return Twin.load(path)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        twin = fifteen_level_twin(d / "twin.json")
        print(f"twin: {len(PAPER_LEVELS)} levels, Kp {twin.parameters['Kp'].model}, wn "
              f"{twin.parameters['wn_rad_s'].model}, zeta {twin.parameters['zeta'].model}")
        export_s = []
        for i in range(3):
            t0 = time.perf_counter()
            res = export_fmu(d / "twin.json", d / f"P15_{i}.fmu")
            export_s.append(time.perf_counter() - t0)
        fmu = str(res.path)
        rE = chirp(FS_HZ, 5.0, 10.0)
        t0 = time.perf_counter()
        twin.simulate(rE, 0.6, FS_HZ)
        sim_s = time.perf_counter() - t0
        exp_med = float(np.median(export_s))
        print(f"1. export incl. compilation: {exp_med:.2f} s (median of 3; target < 10 s: "
              f"{'met' if exp_med < 10 else 'missed'}); "
              f"twin simulate of the 15 s chirp: {sim_s * 1e3:.1f} ms; ratio "
              f"{exp_med / sim_s:.0f}x")

        cases = [(f"sE {s:g}", np.full(len(rE), s)) for s in SE_LEVELS]
        cases.append(("sE ramp 0.2-1.2", np.linspace(0.2, 1.2, len(rE))))
        worst, t_fmpy, t_twin = 0.0, 0.0, 0.0
        for name, sE in cases:
            t0 = time.perf_counter()
            ref = twin.simulate(rE, sE, FS_HZ)
            t_twin += time.perf_counter() - t0
            t0 = time.perf_counter()
            with fmpy_input_derivatives_fixed():
                out = simulate_fmu(fmu, fmi_type="CoSimulation", start_time=0.0,
                                   stop_time=(len(rE) - 1) / FS_HZ, output_interval=1 / FS_HZ,
                                   input=fmpy_input(rE, sE, FS_HZ), set_input_derivatives=True,
                                   output=["force_N"])
            t_fmpy += time.perf_counter() - t0
            err = float(np.max(np.abs(out["force_N"] - ref)) / np.max(np.abs(ref)))
            worst = max(worst, err)
            print(f"   co-sim {name}: max |FMU - twin simulate| = {100 * err:.2e} % of peak")
        print(f"2. co-simulation worst: {100 * worst:.2e} % of peak (limit 1e-4 %: "
              f"{'met' if 100 * worst <= 1e-4 else 'missed'}); FMPy "
              f"{t_fmpy:.2f} s vs twin simulate {t_twin:.3f} s for the same 6 runs "
              f"(ratio {t_fmpy / t_twin:.0f}x)")

        rs = chirp(FS_HZ, 0.5, 2.0)
        cases = [(f"sE {s:g}", np.full(len(rs), s)) for s in SE_LEVELS]
        cases.append(("sE ramp", np.linspace(0.2, 1.2, len(rs))))
        worst_me = fine_me = 0.0
        for name, sE in cases + [("sE ramp, output at step/10", cases[-1][1])]:
            sub = 10 if "step/10" in name else 1
            ref = twin.simulate(rs, sE, FS_HZ)
            t0 = time.perf_counter()
            out = simulate_fmu(fmu, fmi_type="ModelExchange", start_time=0.0,
                               stop_time=(len(rs) - 1) / FS_HZ,
                               output_interval=1 / FS_HZ / sub,
                               input=fmpy_input(rs, sE, FS_HZ, lead=0.0), output=["force_N"],
                               relative_tolerance=1e-8)
            f = on_output_grid(out, "force_N", sub)
            err = float(np.max(np.abs(f - ref)) / np.max(np.abs(ref)))
            if sub == 1:
                worst_me = max(worst_me, err)
            else:
                fine_me = max(fine_me, err)
            print(f"   model exchange {name}: {100 * err:.3f} % of peak "
                  f"({time.perf_counter() - t0:.1f} s)")
        print(f"3. model exchange worst with output at the sampling step: "
              f"{100 * worst_me:.3f} % of peak (FMPy holds inputs between outputs: half an "
              f"output interval late); at a tenth of the step {100 * fine_me:.3f} % "
              f"(target <= 0.1 % there, docs/fmu.md: "
              f"{'met' if 100 * fine_me <= 0.1 else 'missed'}), x"
              f"{worst_me / max(fine_me, 1e-300):.0f} smaller")
    joints_part()


def leg_twins(d: Path) -> Path:
    """LEG1's twin of the elbow, knee and ankle in one file (and each joint's alone)."""
    twins = []
    for joint in ("elbow", "knee", "ankle"):
        data = template_participant(joint).to_twin()
        data.update(participant="LEG1", source=[{"file": f"LEG1-{joint}.h5",
                                                 "sha256": "0" * 64}])
        if joint != "elbow":
            data.update(joint=joint, measured_quantity="torque", measured_unit="N m")
        twin = Twin.from_dict(data)
        twin.save(d / f"LEG1-{joint}.json")
        twins.append(twin)
    return save_joint_twins(d / "LEG1.json", twins)


def joints_part() -> None:
    """Part 4: one FMU of three joints."""
    out_names = {"elbow": "force_N_elbow", "knee": "torque_Nm_knee",
                 "ankle": "torque_Nm_ankle"}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        path = leg_twins(d)
        twins = load_joint_twins(path)
        multi_s, single_s = [], []
        for i in range(3):
            t0 = time.perf_counter()
            res = export_fmu(path, d / f"LEG1_{i}.fmu")
            multi_s.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            for j in twins:
                export_fmu(d / f"LEG1-{j}.json", d / f"LEG1-{j}_{i}.fmu")
            single_s.append(time.perf_counter() - t0)
        m, b = float(np.median(multi_s)), float(np.median(single_s))
        print(f"4. one FMU of 3 joints (elbow + knee + ankle): export incl. compilation "
              f"{m:.2f} s (median of 3; target < 10 s: {'met' if m < 10 else 'missed'}) vs "
              f"3 one-joint FMUs {b:.2f} s (ratio {m / b:.2f}x)")
        rE = chirp(FS_HZ, 5.0, 10.0)
        n = len(rE)
        sE = {"elbow": np.full(n, 0.6), "knee": np.linspace(0.3, 1.0, n),
              "ankle": np.full(n, 0.9)}
        t0 = time.perf_counter()
        with fmpy_input_derivatives_fixed():
            out = simulate_fmu(str(res.path), fmi_type="CoSimulation", start_time=0.0,
                               stop_time=(n - 1) / FS_HZ, output_interval=1 / FS_HZ,
                               input=fmpy_joint_input({j: (rE, sE[j]) for j in twins}, FS_HZ),
                               set_input_derivatives=True, output=list(out_names.values()))
        t_multi = time.perf_counter() - t0
        t_single = 0.0
        worst = 0.0
        for j, twin in twins.items():
            ref = twin.simulate(rE, sE[j], FS_HZ)
            err = float(np.max(np.abs(out[out_names[j]] - ref)) / np.max(np.abs(ref)))
            worst = max(worst, err)
            unit = twin.measured_unit
            print(f"   {j}: {out_names[j]} vs twin simulate --joint {j}: max difference "
                  f"{100 * err:.2e} % of peak ({np.max(np.abs(ref)):.2f} {unit})")
            t0 = time.perf_counter()
            with fmpy_input_derivatives_fixed():
                simulate_fmu(str(d / f"LEG1-{j}_0.fmu"), fmi_type="CoSimulation",
                             start_time=0.0, stop_time=(n - 1) / FS_HZ,
                             output_interval=1 / FS_HZ, input=fmpy_input(rE, sE[j], FS_HZ),
                             set_input_derivatives=True, output=["force_N"])
            t_single += time.perf_counter() - t0
        print(f"   co-simulation worst over the 3 joints: {100 * worst:.2e} % of peak (limit "
              f"1e-4 %: {'met' if 100 * worst <= 1e-4 else 'missed'}); FMPy {t_multi:.2f} s "
              f"for the 3-joint FMU vs {t_single:.2f} s for the 3 one-joint FMUs one after "
              f"the other (ratio {t_multi / t_single:.2f}x)")


if __name__ == "__main__":
    main()
