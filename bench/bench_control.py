"""The twin in the loop: twin-based force control against a twin-free baseline.

For each participant (the template participant and the MuJoCo musculoskeletal one: the
default one and members of the simulator's seeded populations, each with its own
physics) the product path, in process:

1. an identification session (calibration and the paper's schedule, 15 sE x 3, the
   engine of ``nmsid run``), ``nmsid identify`` -> ``twin.json``;
2. ``nmsid control design twin.json`` -> ``controller.json``;
3. a tracking session on the same participant (same seed): the relay-tuned
   Ziegler-Nichols PID (no twin) and the twin-based controller on the same targets
   (steps, ramp, sines 0.2-2 Hz), interleaved;
4. ``nmsid control report`` -> ``tracking.json``.

Printed per participant: RMSE in % of the target range of each controller (mean over
the targets) and the ratio twin / baseline (the baseline is the fairest comparison: same
participant, same session, same targets, same stream and safety path; target <= 0.5);
samples above a ceiling (commanded, from the file, and delivered, from the simulated
stimulator; target 0); the loop's latency from the newest force sample to the updated
output (fast clock: the stream's design figure). Then a real-time tracking session
(``SimRealClock``) measures the latency with the host's real scheduling, with its ratio
to the design figure.

    python bench/bench_control.py                  # 3 participants per model
    python bench/bench_control.py --seeds 1        # quicker (the default ones)
    python bench/bench_control.py --jobs 1         # participants one after another
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.analysis.control.design import ControllerDesign, design_controller  # noqa: E402
from nmsid.analysis.control.targets import Target  # noqa: E402
from nmsid.analysis.twin import Twin  # noqa: E402
from nmsid.cli import main as nmsid  # noqa: E402
from nmsid.protocols.config import config_from_dict, load_config  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402
from nmsid.rig.engine import Engine, TripPolicy  # noqa: E402
from nmsid.rig.tracking import TrackingEngine  # noqa: E402
from nmsid.sim_backends import make_msk_population, make_population, make_sim_rig  # noqa: E402
from nmsid.sim_backends.participant import default_participant  # noqa: E402
from nmsid.sim_backends.participant_models import participant_for_model  # noqa: E402

if str(Path(__file__).resolve().parent) not in sys.path:   # bench/: workers
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from workers import importable, process_pool  # noqa: E402

MODELS = ("template", "musculoskeletal")


def _quiet(*argv) -> int:
    with contextlib.redirect_stdout(io.StringIO()):
        return nmsid([str(a) for a in argv])


def _above_ceiling(rig, session) -> tuple[int, int]:
    """(commanded samples above their stream ceiling, delivered samples above it)."""
    commanded = delivered = 0
    tracking_runs = [r for r in rig.run_records if r.trial is not None]
    for t, rec in zip(session.trials, tracking_runs, strict=False):
        st = json.loads(t.extra_attrs["stream_json"])
        ce, cf = st["ceiling_ext_mA"], st["ceiling_flex_mA"]
        commanded += int(np.count_nonzero(t.I_ext_mA > ce) + np.count_nonzero(t.I_flex_mA > cf))
        I_e, I_f, _ = rig.world.output(rec.N_trigger, rec.N_trigger + t.n_samples)
        delivered += int(np.count_nonzero(I_e > ce) + np.count_nonzero(I_f > cf))
    return commanded, delivered


def participant(model: str, k: int, n: int):
    """Participant k of a model: the default one (k = 0), then members of the simulator's
    seeded population (population seed 28), each with its own physics."""
    if k == 0:
        return participant_for_model(model, 0)
    if model == "template":
        return make_population(n, seed=28)[k - 1]
    return make_msk_population(n, seed=28)[k - 1]


def one(model: str, seed: int, tmp: Path, n: int) -> dict:
    t0 = time.monotonic()
    p = participant(model, seed, n)
    sess = tmp / f"{model}-{seed}-id.h5"
    cfg = load_config(None).replace(participant=f"B{seed:02d}", seed=seed)
    Engine(cfg.with_protocol(rest_s=0.0), make_sim_rig(p), sess,
           trip_policy=TripPolicy.END_SESSION).run()
    ana = tmp / f"{model}-{seed}-ana"
    _quiet("identify", sess, "--out", ana, "--no-figures")
    ctl = tmp / f"{model}-{seed}-ctl"
    assert _quiet("control", "design", ana / "twin.json", "--out", ctl) == 0
    design = ControllerDesign.load(ctl / "controller.json")
    rig = make_sim_rig(p)
    cfg = cfg.with_protocol(rest_s=0.0)
    track = tmp / f"{model}-{seed}-track.h5"
    TrackingEngine(cfg, rig, track, design=design, trip_policy=TripPolicy.END_SESSION).run()
    rep_dir = tmp / f"{model}-{seed}-rep"
    assert _quiet("control", "report", track, "--out", rep_dir) == 0
    rep = json.loads((rep_dir / "tracking.json").read_text())
    s = read_session(track)
    cmd, dlv = _above_ceiling(rig, s)
    lat = [json.loads(t.extra_attrs["stream_json"])["latency_median_s"] for t in s.trials]
    return {"twin": rep["controllers"]["twin"]["rmse_pct_of_range"],
            "baseline": rep["controllers"]["baseline"]["rmse_pct_of_range"],
            "aborted": sum(not t.completed for t in s.trials),
            "above_cmd": cmd, "above_dlv": dlv, "latency_s": float(np.median(lat)),
            "sE": design.sE, "code": getattr(p, "code", ""),
            "seconds": time.monotonic() - t0}


def _one_safe(args: tuple) -> tuple[dict | None, str]:
    """``one`` in a worker: (result, "") or (None, what failed): a bench prints what
    failed and goes on."""
    model, seed, tmp, n = args
    try:
        return one(model, seed, Path(tmp), n), ""
    except Exception as exc:  # noqa: BLE001
        return None, f"{type(exc).__name__}: {exc}"


def outcomes_of(work: list[tuple], jobs: int) -> list[tuple[dict | None, str]]:
    """:func:`_one_safe` of each item, in ``jobs`` worker processes when ``jobs > 1``
    (participants are independent: own files, own seeds), in the order of ``work``."""
    if jobs > 1:
        with process_pool(jobs) as ex:
            return list(ex.map(importable(_one_safe), work))
    return [_one_safe(w) for w in work]


def realtime_latency(tmp: Path) -> dict:
    """A short tracking session on the real-time clock (manual calibration)."""
    p = default_participant(seed=0)
    d = design_controller(Twin.from_dict(p.to_twin()), levels=2)
    d.baseline["relay_s"] = 2.0
    cfg = config_from_dict({
        "participant": "RT", "seed": 1, "protocol": {"rest_s": 0.0},
        "calibration": {"manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                                   "Ifmax_mA": 8.0}}})
    rig = make_sim_rig(p, realtime=True)
    target = Target("sine-1Hz", "sine", {"mean_N": 0.0, "amplitude_N": 1.5, "f_Hz": 1.0}, 4.0)
    TrackingEngine(cfg, rig, tmp / "rt.h5", design=d, targets=[target],
                   trip_policy=TripPolicy.END_SESSION).run()
    s = read_session(tmp / "rt.h5")
    st = [json.loads(t.extra_attrs["stream_json"]) for t in s.trials]
    under = rig.stimulator.last_stream.underrun_updates if rig.stimulator.last_stream else 0
    return {"median": float(np.median([x["latency_median_s"] for x in st])),
            "p99": float(max(x["latency_p99_s"] for x in st)),
            "max": float(max(x["latency_max_s"] for x in st)),
            "late": sum(x["late_updates"] for x in st),
            "n": sum(x["n_updates"] for x in st), "underruns_last": under,
            "compute_max": float(max(x["compute_max_s"] for x in st)),
            "compute_median": float(np.median([x["compute_median_s"] for x in st])),
            "design": (d.queue - 1) / d.update_Hz + 1 / 2000.0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--jobs", type=int, default=2,
                    help="worker processes for the fast-clock participants (2: the bench "
                         "machine's cores); the real-time part runs alone afterwards")
    args = ap.parse_args([] if argv is None else argv)   # bench/run.py calls main()
    logging.disable(logging.WARNING)
    print("1. twin-based controller vs relay-tuned PID (no twin), same participant, session "
          "and targets")
    print("   target: twin RMSE <= 0.5 x baseline; 0 samples above a ceiling")
    print(f"   {'participant':22s} {'sE':>5s} {'twin %':>7s} {'base %':>7s} {'ratio':>6s} "
          f"{'verdict':8s} {'above ceil (cmd/dlv)':>20s} {'latency ms':>10s} {'s':>6s}")
    all_ratios: list[float] = []
    above_total = 0
    with tempfile.TemporaryDirectory(prefix="nmsid-bench-control-") as d:
        tmp = Path(d)
        work = [(model, seed, str(tmp), args.seeds)
                for model in [m for m in args.models.split(",") if m]
                for seed in range(args.seeds)]
        outcomes = outcomes_of(work, args.jobs)
        for (model, seed, _, _), (r, failure) in zip(work, outcomes, strict=True):
            if r is None:
                print(f"   {model} seed {seed}: FAILED ({failure})")
                continue
            ratio = r["twin"] / r["baseline"]
            all_ratios.append(ratio)
            above_total += r["above_cmd"] + r["above_dlv"]
            verdict = "met" if ratio <= 0.5 else "missed"
            label = f"{model} {r['code']}"
            print(f"   {label:22s} {r['sE']:5.2f} {r['twin']:7.2f} "
                  f"{r['baseline']:7.2f} {ratio:6.3f} {verdict:8s} "
                  f"{str(r['above_cmd']) + ' / ' + str(r['above_dlv']):>20s} "
                  f"{1000 * r['latency_s']:10.2f} {r['seconds']:6.1f}"
                  + (f"  ({r['aborted']} aborted)" if r["aborted"] else ""))
        if all_ratios:
            print(f"   worst ratio {max(all_ratios):.3f} over {len(all_ratios)} participants: "
                  f"{'met' if max(all_ratios) <= 0.5 else 'missed'} (target <= 0.5); samples "
                  f"above a ceiling: {above_total} "
                  f"({'met' if above_total == 0 else 'missed'}, target 0)")
        print("2. loop latency on the real-time clock (force sample -> updated output), "
              "one tracking session, template participant")
        load = getattr(os, "getloadavg", lambda: (float("nan"),) * 3)()[0]
        rt = realtime_latency(tmp)
        load_after = getattr(os, "getloadavg", lambda: (float("nan"),) * 3)()[0]
        print(f"   median {1000 * rt['median']:.2f} ms, p99 {1000 * rt['p99']:.2f} ms, max "
              f"{1000 * rt['max']:.2f} ms over {rt['n']} updates; late updates {rt['late']}; "
              f"host compute median {1000 * rt['compute_median']:.3f} ms, max "
              f"{1000 * rt['compute_max']:.2f} ms (load average {load:.2f} -> "
              f"{load_after:.2f} on {os.cpu_count()} cores: late updates come from the "
              "host's scheduling, and play at zero)")
        print(f"   ratio median / design figure ({1000 * rt['design']:.2f} ms: one queued "
              f"update + one sample): {rt['median'] / rt['design']:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
