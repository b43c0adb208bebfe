"""``nmsid gap``: where the simulation misses, which unmodelled effect explains it, and how
far adding that effect shrinks the gap on held-out trials.

    nmsid gap SESSION.h5 [SESSION.h5 ...] --out DIR [--twin TWIN.json | --sim-session SIM.h5]

Registering imports nothing heavy; the handler imports the analysis when it runs.
"""

from __future__ import annotations

import argparse


def register(sub) -> None:
    """Add the ``gap`` sub-command."""
    p = sub.add_parser(
        "gap", help="diagnose the sim-to-real gap (where, which effect, how far it shrinks)",
        description="Fit the nominal twin (second order per sE) and six candidate "
                    "augmentations (dead_time, activation_dynamics, fatigue, "
                    "recruitment_nonlinearity, baseline_drift, flexor_extensor_asymmetry) "
                    "on training repeats, score them on held-out repeats (3-fold "
                    "cross-validation by repeat) and by an information criterion with the "
                    "effective number of samples, localise the gap, and write "
                    "gap_report.json, report.html with figures, and the augmented twin.json. "
                    "See docs/gap.md.")
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5", help="session file(s)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--twin", metavar="TWIN.json",
                     help="simulation under test: this twin file instead of the nominal "
                          "twin fitted on the training trials (used for the 'where' part)")
    src.add_argument("--sim-session", metavar="SIM.h5",
                     help="simulation under test: a simulated session (trials matched by "
                          "sE and repeat)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-pairs", action="store_true",
                   help="do not try the winner together with a second effect")
    p.add_argument("--ic-margin", type=float, default=10.0, metavar="D",
                   help="an effect needs dIC below -D (default 10)")
    p.add_argument("--min-shrink-pct", type=float, default=10.0, metavar="P",
                   help="an effect must cut the held-out NRMSE by P %% (default 10)")
    p.set_defaults(handler="analysis.cli_gap:run")


def run(args: argparse.Namespace) -> int:
    """Handler of ``nmsid gap``."""
    from analysis.gap.api import GapSettings, run_gap

    settings = GapSettings(ic_margin=args.ic_margin, min_shrink_pct=args.min_shrink_pct,
                           try_pairs=not args.no_pairs)
    summary = run_gap(args.sessions, args.out, settings=settings, twin=args.twin,
                      sim_session=args.sim_session, plots=not args.no_figures)
    for s in summary["sessions"]:
        h = s["heldout"]
        print(f"{s['session']}: verdict = {s['verdict']}, best_effect = {s['best_effect']}"
              + (f" (pair {' + '.join(s['best_pair'])})" if s.get("best_pair") else "")
              + f"; held-out NRMSE {h['nominal_nrmse_pct']:.3g} % -> "
              f"{h['augmented_nrmse_pct']:.3g} % (shrink {h['shrink_pct']:.0f} %); noise floor "
              f"{h['noise_floor_nrmse_pct']:.3g} % between repeats, "
              + (f"{h['sensor_floor_nrmse_pct']:.3g} %" if h.get("sensor_floor_nrmse_pct")
                 is not None else "n/a")
              + f" in the steady lead-in  [{s['elapsed_s']:.1f} s]")
        print(f"  {s['verdict_sentence']}")
        for line in s["evidence"]["summary"]:
            print(f"  {line}")
        if s.get("simulation_under_test"):
            u = s["simulation_under_test"]
            print(f"  simulation under test {u['source']}: NRMSE {u['nrmse_pct']:.3g} % on all "
                  "trials (nothing of it fitted here)")
    print(f"report: {summary['report']}")
    return 0
