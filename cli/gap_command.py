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
        for line in session_lines(s):
            print(line)
    print(f"report: {report_path}")
    return 0


def _g(v, spec: str = ".3g") -> str:
    """A figure of the report, or ``n/a`` when it could not be computed (None in JSON)."""
    return "n/a" if v is None else format(v, spec)


def session_lines(s: dict) -> list[str]:
    """What ``nmsid gap`` prints of one session's report: every figure that could not be
    computed (a fit that did not converge) shows as ``n/a``, never a crash."""
    h = s["heldout"]
    out = [f"{s['session']}: verdict = {s['verdict']}, best_effect = {s['best_effect']}"
           + (f" (pair {' + '.join(s['best_pair'])})" if s.get("best_pair") else "")
           + f"; held-out NRMSE {_g(h['nominal_nrmse_pct'])} % -> "
           f"{_g(h['augmented_nrmse_pct'])} % (shrink {_g(h['shrink_pct'], '.0f')} %); noise "
           f"floor {_g(h['noise_floor_nrmse_pct'])} % between repeats, "
           f"{_g(h.get('sensor_floor_nrmse_pct'))} % in the steady lead-in  "
           f"[{_g(s.get('elapsed_s'), '.1f')} s]",
           f"  {s['verdict_sentence']}"]
    m = s.get("muscle_twin")
    if m and not m.get("converged", True):
        out.append(f"  muscle twin: not scored - {m.get('note') or 'the fit did not converge'}"
                   f"; fitted for {_g(m.get('fit_s'), '.0f')} s")
    elif m:
        mh = m["heldout"]
        out.append(f"  muscle twin ({'supported' if m['supported'] else 'not supported'}): "
                   f"held-out NRMSE {_g(mh['nominal_nrmse_pct'])} % nominal, "
                   f"{_g(mh['template_nrmse_pct'])} % {mh['template']} -> "
                   f"{_g(mh['muscle_nrmse_pct'])} % (noise floor "
                   f"{_g(mh['noise_floor_nrmse_pct'])} %); fitted in "
                   f"{_g(m.get('fit_s'), '.0f')} s; not determined by the data: "
                   f"{', '.join(m.get('not_determined') or []) or 'none'}")
    out += [f"  {line}" for line in s["evidence"]["summary"]]
    for f in s.get("figures_failed") or []:
        out.append(f"  figure {f['figure']} not drawn: {f['reason']}")
    u = s.get("simulation_under_test")
    if u:
        out.append(f"  simulation under test {u['source']}: NRMSE {_g(u['nrmse_pct'])} % on "
                   "all trials (nothing of it fitted here)")
    return out
