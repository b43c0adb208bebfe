"""Benchmark of the default ``nmsid gap`` on a varied corpus (issue 40): no crash, "likely X"
under scatter, fatigue intervals that hold for linear and saturating losses.

Every session runs the *default* command (figures on, muscle twin on, pairs on) in its own
process, ``python -m nmsid gap SESSION --out DIR``, as a user would; a non-zero exit
(e.g. "internal error") is a crash. Sessions come from
:func:`nmsid.testing.sessions.write_physiology_session` (two antagonist muscles, scipy's
first-order-hold discretisation, written independently of nmsid's simulator and analysis)
and :func:`nmsid.testing.sessions.write_gap_session` (a fixed second-order participant),
cycling through these generators (the seed draws magnitudes, curves, noise 0.01-0.05 N
and blocks or full randomisation):

* ``fatigue_linear`` / ``fatigue_saturating``: 15-35 % of the gain lost over the session,
  linearly or saturating (time constant 10-30 % of the session's stimulation), under
  5/3/3 % or 10/5/5 % trial-to-trial scatter of Kp/wn/zeta; 10 sE x 3 repeats. Target:
  the gap's 95 % interval of the loss covers the truth in >= 90 % of each shape.
* ``recruitment`` (sigmoid, power or threshold-saturation curve) and ``asymmetry`` (flexor
  wn 1.3-1.8x or its inverse, zeta 0.7-1.4x) under 10/5/5 % scatter, 15 sE x 3. Target:
  named (effect or pair) or "likely X" with the right X in >= 90 %; "something else" never.
* ``scatter`` (10/5/5 and 20/10/10 %), ``dead_time`` under scatter, ``drift`` (0.2-0.4 N
  below 0.1-0.3 Hz) under scatter, ``step`` (a baseline step in one trial),
  ``co_contraction`` (a repeatable gap no candidate explains: the muscle twin is tried) and
  ``tremor`` (template sessions): must not crash; verdicts are printed.

    python bench/bench_gap_corpus.py [--sessions 60] [--jobs 1] [--keep DIR]
        [--only KIND,KIND] [--start I]

The session count is a parameter (the machine is shared): kinds are dealt round-robin from
a round of 18 with each fatigue shape 4 times, so 60 sessions give 14 of each shape;
``--only fatigue_linear,fatigue_saturating --start 60 --sessions 12`` adds 6 of each on
other seeds (session ``i`` has seed ``1000 + i``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import as_completed
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from rates import rate  # noqa: E402
from workers import importable, process_pool  # noqa: E402

#: One round of the deal (fatigue shapes twice: >= 20 of each in 60 sessions).
ROUND = ("fatigue_linear", "fatigue_saturating", "recruitment", "fatigue_linear",
         "fatigue_saturating", "asymmetry", "scatter", "dead_time", "drift", "step",
         "co_contraction", "tremor", "fatigue_linear", "fatigue_saturating", "recruitment",
         "fatigue_linear", "fatigue_saturating", "asymmetry")

LIBRARY = {"recruitment": "recruitment_nonlinearity", "asymmetry": "flexor_extensor_asymmetry",
           "dead_time": "dead_time"}

LEVELS_15 = tuple(round(0.30 + 0.05 * i, 2) for i in range(15))
LEVELS_10 = tuple(float(v) for v in np.round(np.linspace(0.3, 1.0, 10), 3))


def kinds(n: int, only: tuple[str, ...] = ()) -> list[str]:
    """The first ``n`` kinds of the deal (of ``only``'s kinds, in their order, if given)."""
    deal = tuple(only) or ROUND
    return [deal[i % len(deal)] for i in range(n)]


def write(kind: str, seed: int, path: str) -> dict:
    """Write one session of ``kind``; returns what the bench knows of its truth."""
    from nmsid.testing.sessions import write_gap_session, write_physiology_session
    rng = np.random.default_rng([seed, 4041, ROUND.index(kind)])
    common = {"seed": seed, "noise_N": float(rng.uniform(0.01, 0.05)),
              "randomisation": ("blocks", "full")[seed % 2]}
    truth: dict = {"kind": kind}
    if kind.startswith("fatigue_"):
        shape = kind.split("_")[1]
        loss = float(rng.uniform(0.15, 0.35))
        tau = float(rng.uniform(0.10, 0.30))
        cv = ((0.05, 0.03, 0.03), (0.10, 0.05, 0.05))[(seed // 2) % 2]
        t = write_physiology_session(path, levels=LEVELS_10, cv=cv,
                                     fatigue=(shape, loss, tau), **common)
        truth.update(loss_pct=t["loss_pct"], cv=cv, shape=shape)
    elif kind == "recruitment":
        spec = (("sigmoid", float(rng.uniform(7, 12)), float(rng.uniform(0.4, 0.6))),
                ("power", float(rng.choice([rng.uniform(1.8, 2.5), rng.uniform(0.4, 0.6)]))),
                ("threshold", float(rng.uniform(0.05, 0.15)), float(rng.uniform(0.7, 0.9)))
                )[seed % 3]
        write_physiology_session(path, levels=LEVELS_15, recruitment=spec, **common)
        truth["spec"] = spec
    elif kind == "asymmetry":
        r = float(rng.uniform(1.3, 1.8))
        spec = (r if seed % 2 else 1 / r, float(rng.uniform(0.7, 1.4)))
        write_physiology_session(path, levels=LEVELS_15, asymmetry=spec, **common)
        truth["spec"] = spec
    elif kind == "scatter":
        cv = ((0.10, 0.05, 0.05), (0.20, 0.10, 0.10))[seed % 2]
        write_physiology_session(path, levels=LEVELS_15, cv=cv, **common)
        truth["cv"] = cv
    elif kind == "dead_time":
        L = float(rng.uniform(0.015, 0.040))
        write_physiology_session(path, levels=LEVELS_15, dead_time_s=L, **common)
        truth["L_s"] = L
    elif kind == "drift":
        write_physiology_session(path, levels=LEVELS_10, drift=(float(rng.uniform(0.2, 0.4)),
                                                                float(rng.uniform(0.1, 0.3))),
                                 **common)
    elif kind == "step":
        write_physiology_session(path, levels=LEVELS_10, cv=(0.03, 0.02, 0.02),
                                 step=(int(rng.integers(0, 30)), float(rng.uniform(6, 13)),
                                       float(rng.choice([-1, 1]) * rng.uniform(0.5, 2.0))),
                                 **common)
    elif kind == "co_contraction":
        write_gap_session(path, seed=seed, co_contraction=(float(rng.uniform(0.3, 0.8)), 0.05),
                          noise_N=common["noise_N"])
    elif kind == "tremor":
        write_gap_session(path, seed=seed, tremor=(float(rng.uniform(7, 11)),
                                                   float(rng.uniform(0.05, 0.2))),
                          noise_N=common["noise_N"])
    else:
        raise ValueError(kind)
    return truth


def run_case(args) -> dict:
    """Write one session and run the default ``nmsid gap`` on it in its own process."""
    i, kind, tmp = args
    path = os.path.join(tmp, f"s{i:03d}_{kind}.h5")
    out = os.path.join(tmp, f"o{i:03d}")
    truth = write(kind, 1000 + i, path)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "nmsid", "gap", path, "--out", out],
                       capture_output=True, text=True, timeout=3600)
    row = {"i": i, "kind": kind, "truth": truth, "exit": p.returncode,
           "elapsed_s": time.perf_counter() - t0,
           "stderr_tail": "\n".join(p.stderr.strip().splitlines()[-3:])}
    rep_path = Path(out) / "gap_report.json"
    if p.returncode == 0 and rep_path.exists():
        rep = json.loads(rep_path.read_text())
        m = rep.get("muscle_twin") or {}
        row.update(verdict=rep["verdict"], best=rep["best_effect"],
                   pair=rep.get("best_pair") or [], sentence=rep["verdict_sentence"],
                   likely=(rep.get("likely") or {}).get("label"), fatigue=rep.get("fatigue"),
                   figures=len(rep.get("figures") or []),
                   figures_failed=rep.get("figures_failed") or [],
                   muscle=("not converged" if m and not m.get("converged", True) else
                           "supported" if m.get("supported") else "tried" if m else ""),
                   twin_fatigue=bool((rep.get("fatigue_in_twin") or {}).get("entry")))
    return row


def _lo(f: dict) -> float:
    """The interval's low end (None in JSON: -inf, an interval open downwards)."""
    return f["ci_low_pct"] if f["ci_low_pct"] is not None else -float("inf")


def _named(r: dict, label: str) -> bool:
    return label in (r.get("best"), *r.get("pair", [])) or r.get("likely") == label


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=60)
    ap.add_argument("--jobs", type=int, default=1,
                    help="worker processes (default 1: the machine is shared)")
    ap.add_argument("--keep", default=None, help="keep sessions and reports in this folder")
    ap.add_argument("--only", default="", help="comma-separated kinds to deal (default all)")
    ap.add_argument("--start", type=int, default=0, help="index (and seed) of the first")
    a = ap.parse_args(argv if argv is not None else sys.argv[1:])
    only = tuple(k for k in a.only.split(",") if k)
    bad = [k for k in only if k not in ROUND]
    if bad:
        ap.error(f"--only {','.join(bad)}: kinds are {', '.join(sorted(set(ROUND)))}")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = a.keep or tmp_
        os.makedirs(tmp, exist_ok=True)
        cases = [(a.start + i, k, tmp) for i, k in enumerate(kinds(a.sessions, only))]
        rows = []
        if a.jobs > 1:
            with process_pool(a.jobs) as ex:
                futures = [ex.submit(importable(run_case), c) for c in cases]
                for fut in as_completed(futures):
                    rows.append(fut.result())
                    _progress(rows[-1])
        else:
            for c in cases:
                rows.append(run_case(c))
                _progress(rows[-1])
    report(sorted(rows, key=lambda r: r["i"]), time.perf_counter() - t0)


def _progress(r: dict) -> None:
    print(f"{r['i']:3d} {r['kind']:<19} exit {r['exit']} {r.get('verdict', '-'):<12} "
          f"{r.get('best', '-'):<26} {r.get('likely') or '':<26} {r['elapsed_s']:6.0f} s",
          flush=True)


def report(rows: list[dict], wall_s: float) -> None:
    n = len(rows)
    crashes = [r for r in rows if r["exit"] != 0]
    figfail = [r for r in rows if r.get("figures_failed")]
    print(f"\nDefault `nmsid gap` (figures, muscle twin, pairs) on {n} sessions, "
          f"{wall_s / 60:.1f} min")
    print("crashes (non-zero exit): " + rate(len(crashes), n, "<=", 0.0))
    for r in crashes:
        print(f"  {r['i']} {r['kind']}: exit {r['exit']}: {r['stderr_tail']}")
    print(f"sessions with a figure not drawn: {len(figfail)} of {n}")
    for r in figfail:
        print(f"  {r['i']} {r['kind']}: {r['figures_failed']}")
    muscle = [r.get("muscle") for r in rows if r.get("muscle")]
    print(f"muscle twin tried on {len(muscle)}: "
          + ", ".join(f"{k} {muscle.count(k)}" for k in sorted(set(muscle))))
    lib = [r for r in rows if r["kind"] in ("recruitment", "asymmetry") and "verdict" in r]
    ok = [r for r in lib if _named(r, LIBRARY[r["kind"]])]
    else_ = [r for r in lib if "something else" in r["sentence"]]
    print("library effects under 10/5/5 % scatter named or 'likely X' (right X): "
          + rate(len(ok), len(lib), ">=", 90.0))
    print("  'something else' on them: " + rate(len(else_), len(lib), "<=", 0.0))
    for r in lib:
        print(f"  {r['kind']:<12} {r['verdict']:<12} best {r['best']:<26} likely "
              f"{r.get('likely') or '-':<26} {r['truth']['spec']}")
    for shape in ("linear", "saturating"):
        fr = [r for r in rows if r["kind"] == f"fatigue_{shape}" and r.get("fatigue")]
        cover = [r for r in fr if _lo(r["fatigue"]) <= r["truth"]["loss_pct"]
                 <= (r["fatigue"]["ci_high_pct"] if r["fatigue"]["ci_high_pct"] is not None
                     else 100.0)]
        sig = [r for r in fr if r["fatigue"]["significant"]]
        print(f"fatigue {shape}: 95 % interval covers the truth: "
              + rate(len(cover), len(fr), ">=", 90.0)
              + f"; significant {len(sig)} of {len(fr)}, in twin.json "
              f"{sum(r['twin_fatigue'] or 'fatigue' in (r['best'], *r['pair']) for r in sig)}"
              f" of those")
        for r in fr:
            f = r["fatigue"]
            print(f"  true {r['truth']['loss_pct']:5.1f}  gap {f['loss_pct']:5.1f} "
                  f"[{_lo(f):5.1f}, {f['ci_high_pct']:5.1f}] {f['shape']:<11} "
                  f"cv {r['truth']['cv'][0]:.2f} sig {f['significant']!s:<5} "
                  f"verdict {r['verdict']} {r['best']}")
    other = [r for r in rows if r["kind"] in ("scatter", "dead_time", "drift", "step",
                                               "co_contraction", "tremor") and "verdict" in r]
    for r in other:
        print(f"  {r['kind']:<15} {r['verdict']:<12} best {r['best']:<22} "
              f"likely {r.get('likely') or '-'}: {r['sentence'][:150]}")


if __name__ == "__main__":
    main()
