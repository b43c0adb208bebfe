"""The musculoskeletal participant (MuJoCo elbow under FES) beside the template participant.

1. A whole session (both calibration ramps + 45 trials, fast clock) through the engine, per
   participant (two at a time, one per core): wall and CPU time, file valid, calibration vs the
   noise-free ramp, then identification against the participant's truth (the template: its curves;
   the musculoskeletal one: the best second-order description of its noise-free response,
   ``MskParticipant.second_order_truth``), worst error per parameter over the 15 sE and
   the fit % reached vs the fit % a second-order model can reach at all.
2. ``nmsid run --backend sim --participant-model musculoskeletal`` as a user runs it
   (a subprocess: imports, engine, HDF5), then ``nmsid validate``.
3. Per sE for the default musculoskeletal participant: identified vs truth.
4. Real time: simulation throughput (MuJoCo steps/s, one step a sample) and a 5 s run on
   the real-time clock through the devices (achieved samples/s vs 2000).
5. ``nmsid gap`` on the default musculoskeletal session: best effect, held-out NRMSE, and
   the verdict / remaining part where the gap report has them.

Goals: session < 30 s; identification within 1 % of the best second-order description.

    python bench/run.py musculoskeletal
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.protocols.session_file import read_session, validate_session  # noqa: E402
from nmsid.rig.engine import Engine, TripPolicy  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402

if str(Path(__file__).resolve().parent) not in sys.path:   # bench/: workers
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from workers import importable, process_pool  # noqa: E402

PARAMS = ("Kp", "wn_rad_s", "zeta")


def _session(participant, code: str, tmp: Path) -> dict:
    from nmsid.analysis.identify import identify_session

    rig = make_sim_rig(participant)
    cfg = config_from_dict({"participant": code, "seed": 7, "protocol": {"rest_s": 0.0}})
    path = tmp / f"{code}.h5"
    t0, c0 = time.perf_counter(), time.process_time()
    summary = Engine(cfg, rig, path, trip_policy=TripPolicy.END_SESSION).run()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    valid = validate_session(path) == [] and summary.n_completed == 45
    cal = read_session(path, load_data=False).calibration
    names = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA")
    if hasattr(participant, "ramp_calibration") and hasattr(participant, "second_order_truth"):
        pred = participant.ramp_calibration()
    else:
        pred = participant.calibration
    cal_ok = all(getattr(cal, n) == getattr(pred, n) for n in names)
    t1 = time.perf_counter()
    res = identify_session(path)
    t_ident = time.perf_counter() - t1
    t2 = time.perf_counter()
    rows = []
    for lv in res.levels:
        if hasattr(participant, "second_order_truth"):
            tr = participant.second_order_truth(lv.sE, cal)
            truth, fit_ceiling = (tr.Kp, tr.wn_rad_s, tr.zeta), tr.fit_pct
        else:
            truth, fit_ceiling = tuple(participant.true_parameters(lv.sE, cal)), float("nan")
        got = (lv.fit.Kp, lv.fit.wn_rad_s, lv.fit.zeta)
        rows.append({"sE": lv.sE, "got": got, "truth": truth, "fit": lv.fit.fit_pct,
                     "ceiling": fit_ceiling,
                     "err": [100.0 * (g / t - 1.0) for g, t in zip(got, truth, strict=True)]})
    t_truth = time.perf_counter() - t2
    return {"code": code, "wall": wall, "cpu": cpu, "valid": valid, "cal_ok": cal_ok,
            "cal": tuple(getattr(cal, n) for n in names), "t_ident": t_ident,
            "t_truth": t_truth, "rows": rows, "path": path}


def _print_sessions(results) -> None:
    print("1. whole session (ramps + 45 trials, fast clock, engine + HDF5), then "
          "identification vs truth")
    head = (f"{'participant':<26}{'session s':>10}{'CPU s':>7}{'valid':>6}{'cal=ramp':>9}"
            f"{'ident s':>8}{'|dKp| %':>9}{'|dwn| %':>9}{'|dzeta| %':>10}"
            f"{'fit % (id)':>13}{'2nd-order ceiling %':>21}")
    print(head)
    for name, r in results:
        worst = [max(abs(row["err"][k]) for row in r["rows"]) for k in range(3)]
        fits = [row["fit"] for row in r["rows"]]
        ceil = [row["ceiling"] for row in r["rows"]]
        ceil_s = "n/a (exact)" if np.isnan(ceil).all() else f"{min(ceil):.1f}-{max(ceil):.1f}"
        print(f"{name:<26}{r['wall']:>10.1f}{r['cpu']:>7.1f}{str(r['valid']):>6}"
              f"{str(r['cal_ok']):>9}{r['t_ident']:>8.2f}{worst[0]:>9.3f}{worst[1]:>9.3f}"
              f"{worst[2]:>10.3f}{f'{min(fits):.1f}-{max(fits):.1f}':>13}{ceil_s:>21}")
    print("(worst over the 15 sE levels; truth: template = its curves, musculoskeletal = "
          "best 2nd-order fit of its noise-free response, computed in "
          + ", ".join(f"{r['t_truth']:.1f} s" for n, r in results if "musc" in n) + ")")
    slow = max(r["wall"] for _, r in results)
    worst_all = max(max(abs(row["err"][k]) for row in r["rows"] for k in range(3))
                    for _, r in results)
    print(f"goals: session < 30 s: {'met' if slow < 30 else 'missed'} (slowest {slow:.1f} s); "
          f"identification within 1 % of the truth: {'met' if worst_all <= 1 else 'missed'} "
          f"(worst {worst_all:.3f} %)")


def _print_levels(r) -> None:
    print(f"\n3. per sE, default musculoskeletal participant (calibration {r['cal']} mA)")
    print(f"{'sE':>5}{'Kp id/truth':>20}{'wn id/truth':>20}{'zeta id/truth':>20}"
          f"{'fit id/ceiling %':>19}")
    for row in r["rows"]:
        g, t = row["got"], row["truth"]
        kp, wn = f"{g[0]:.3f}/{t[0]:.3f}", f"{g[1]:.2f}/{t[1]:.2f}"
        ze, fit = f"{g[2]:.3f}/{t[2]:.3f}", f"{row['fit']:.1f}/{row['ceiling']:.1f}"
        print(f"{row['sE']:>5.2f}{kp:>20}{wn:>20}{ze:>20}{fit:>19}")


def _cli_session(tmp: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    out = tmp / "cli.h5"
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim",
                        "--participant-model", "musculoskeletal", "--participant", "CLI1",
                        "--out", str(out), "--quiet", "--no-identify"], env=env, cwd=ROOT,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    v = subprocess.run([sys.executable, "-m", "nmsid.cli", "validate", str(out)], env=env,
                       cwd=ROOT, capture_output=True, text=True)
    print("\n2. nmsid run --backend sim --participant-model musculoskeletal --no-identify "
          "(subprocess, imports included)")
    print(f"   exit {p.returncode}, {wall:.1f} s wall; nmsid validate: "
          f"{(v.stdout or v.stderr).strip()}")


def _realtime() -> None:
    from nmsid.sim_backends.direct_drive import chirp_rE, currents_for, run_waveform, waveform
    from nmsid.sim_backends.msk_participant import default_msk_participant
    from nmsid.sim_backends.msk_simulation import MskSimulator
    from nmsid.sim_backends.participant import default_participant
    from nmsid.sim_backends.simulation import ParticipantSimulator

    print("\n4. real time (2000 samples/s needed)")
    p = default_msk_participant()
    cal = p.ramp_calibration()
    I_e, I_f = currents_for(cal, 0.6, chirp_rE())
    for name, sim in (("musculoskeletal", MskSimulator(p)),
                      ("template", ParticipantSimulator(default_participant()))):
        best = min(_timed(lambda sim=sim: sim.simulate(I_e, I_f)) for _ in range(3))
        print(f"   {name:<16} simulation of a 15 s trial: {best * 1e3:7.1f} ms = "
              f"{I_e.size / best:>10,.0f} samples/s ({I_e.size / best / 2000:,.0f} x real time)")
    rig = make_sim_rig(p, realtime=True, connect=True)
    n = 5 * 2000
    wf = waveform(I_e[5 * 2000:5 * 2000 + n], I_f[5 * 2000:5 * 2000 + n])
    t0 = time.perf_counter()
    force, chunks = run_waveform(rig, wf)
    wall = time.perf_counter() - t0
    got = int(np.isfinite(force).sum())
    print(f"   real-time clock, 5 s chirp through the devices: {got} samples in {wall:.3f} s "
          f"= {got / wall:,.0f} samples/s (pace {got / wall / 2000:.3f} of real time), "
          f"{len(chunks)} chunks, overrun flags: "
          f"{sum(1 for c in chunks if c.flags.overrun)}")


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _gap(path: Path, tmp: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    out = tmp / "gap"
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "nmsid.cli", "gap", str(path), "--out", str(out),
                        "--no-figures"], env=env, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    print(f"\n5. nmsid gap on the default musculoskeletal session (exit {p.returncode}, "
          f"{wall:.1f} s)")
    for line in (p.stdout or p.stderr).strip().splitlines():
        print("   " + line)
    if p.returncode == 0:
        rep = json.loads((out / "gap_report.json").read_text())
        h = rep["heldout"]
        print(f"   best_effect {rep['best_effect']}, best_pair {rep.get('best_pair')}, "
              f"params {json.dumps(rep.get('best_params'))}")
        print(f"   held-out fit {h['nominal_fit_pct']:.1f} % -> {h['augmented_fit_pct']:.1f} % "
              f"(NRMSE {h['nominal_nrmse_pct']:.2f} % -> {h['augmented_nrmse_pct']:.2f} %, "
              f"noise floor {h['noise_floor_nrmse_pct']:.2f} %)")
        for key in ("verdict", "remaining"):
            print(f"   {key}: " + (json.dumps(rep[key]) if key in rep else
                                   "not in this build's gap report"))


def _participant(spec: tuple[str, int]):
    from nmsid.sim_backends.msk_participant import default_msk_participant
    from nmsid.sim_backends.msk_population import make_msk_population
    from nmsid.sim_backends.participant import default_participant
    kind, k = spec
    if kind == "template":
        return default_participant(seed=k)
    if kind == "musculoskeletal":
        return default_msk_participant(seed=k)
    return make_msk_population(2, seed=1)[k]


def _session_of(args: tuple) -> dict:
    """One part-1 session in a worker (the participant is built there: MuJoCo models are
    not sent between processes)."""
    spec, code, tmp = args
    logging.disable(logging.WARNING)
    return _session(_participant(spec), code, Path(tmp))


SESSIONS = ((("template", 11), "T11", "template (default, seed 11)"),
            (("musculoskeletal", 5), "MSK", "musculoskeletal (default)"),
            (("population", 0), "M01", "musculoskeletal M01 (pop 1)"),
            (("population", 1), "M02", "musculoskeletal M02 (pop 1)"))


def main(jobs: int = 2) -> None:
    """``jobs``: part 1's sessions side by side (2: one per core of the bench machine;
    each session's wall and CPU time are its own); the real-time part runs alone."""
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        work = [(spec, code, str(tmp)) for spec, code, _ in SESSIONS]
        if jobs > 1:
            with process_pool(jobs) as ex:
                outs = list(ex.map(importable(_session_of), work))
        else:
            outs = [_session_of(w) for w in work]
        results = [(label, out) for (_, _, label), out in zip(SESSIONS, outs, strict=True)]
        _print_sessions(results)
        print(f"({jobs} session(s) at a time)")
        _cli_session(tmp)
        _print_levels(results[1][1])
        _realtime()
        _gap(results[1][1]["path"], tmp)


if __name__ == "__main__":
    main()
