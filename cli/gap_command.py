"""The handler of ``nmsid gap`` (registered by :mod:`nmsid.cli.gap`)."""

from __future__ import annotations

import argparse

from nmsid.analysis.gap.api import GapSettings, run_gap


def run(args: argparse.Namespace) -> int:
    """Handler of ``nmsid gap``."""
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
