"""Handler of ``nmsid study`` (registered by :mod:`nmsid.cli.study`; Dask loads here)."""

from __future__ import annotations

from nmsid.study.config import load_study
from nmsid.study.runner import run_study


def run(args) -> int:
    cfg = load_study(args.study)
    if args.no_gap:
        cfg.gap = False
    out = run_study(cfg, args.out, workers=args.workers, scheduler=args.scheduler)
    n_bad = sum(1 for r in out.results if not r.get("ok"))
    print(f"{len(out.results)} session(s), {n_bad} failed, {out.elapsed_s:.1f} s "
          f"({out.mode}); report: {out.report}")
    return 1 if n_bad else 0
