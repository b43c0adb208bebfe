"""The handler of ``nmsid gap`` (registered by :mod:`nmsid.cli.gap`)."""

from __future__ import annotations

import argparse
import math

from nmsid.analysis.gap.api import GapSettings, run_gap
from nmsid.analysis.gap.errors import GapInputError
from nmsid.protocols.output_paths import output_dir


def run(args: argparse.Namespace) -> int:
    """Handler of ``nmsid gap``."""
    if not (math.isfinite(args.ic_margin) and 0 <= args.ic_margin <= 1000):
        raise GapInputError(f"--ic-margin {args.ic_margin:g}: an information-criterion "
                            "margin in [0, 1000] (default 10)")
    if not (math.isfinite(args.min_shrink_pct) and 0 <= args.min_shrink_pct <= 100):
        raise GapInputError(f"--min-shrink-pct {args.min_shrink_pct:g}: a percentage in "
                            "[0, 100] (default 10)")
    settings = GapSettings(ic_margin=args.ic_margin, min_shrink_pct=args.min_shrink_pct,
                           try_pairs=not args.no_pairs,
                           try_muscle=not getattr(args, "no_muscle", False),
                           skip_settled=not getattr(args, "all_candidates", False),
                           progress=True)
    with output_dir(args.out, force=args.force) as tmp:
        summary = run_gap(args.sessions, tmp, settings=settings, twin=args.twin,
                          sim_session=args.sim_session, plots=not args.no_figures)
    report_path = str(summary.report).replace(str(tmp), str(args.out))
    for s in summary.sessions:
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
        m = s.get("muscle_twin")
        if m:
            mh = m["heldout"]
            print(f"  muscle twin ({'supported' if m['supported'] else 'not supported'}): "
                  f"held-out NRMSE {mh['nominal_nrmse_pct']:.3g} % nominal, "
                  f"{mh['template_nrmse_pct']:.3g} % {mh['template']} -> "
                  f"{mh['muscle_nrmse_pct']:.3g} % (noise floor "
                  f"{mh['noise_floor_nrmse_pct']:.3g} %); fitted in {m['fit_s']:.0f} s; not "
                  f"determined by the data: {', '.join(m['not_determined']) or 'none'}")
        for line in s["evidence"]["summary"]:
            print(f"  {line}")
        if s.get("simulation_under_test"):
            u = s["simulation_under_test"]
            print(f"  simulation under test {u['source']}: NRMSE {u['nrmse_pct']:.3g} % on all "
                  "trials (nothing of it fitted here)")
    print(f"report: {report_path}")
    return 0
