"""Handler of ``nmsid study`` (registered by :mod:`nmsid.cli.study`; Dask loads here)."""

from __future__ import annotations

from nmsid.cli.errors import UsageError
from nmsid.protocols.output_paths import check_output, output_dir
from nmsid.protocols.user_values import non_utf8_problem
from nmsid.study.config import load_study
from nmsid.study.runner import run_study


def run(args) -> int:
    check_output(args.out, force=args.force, kind="folder")
    cfg = load_study(args.study)
    for session in cfg.sessions:  # one line, before any session is read or reported
        problem = non_utf8_problem(str(session))
        if problem:
            raise UsageError(f"{args.study}: session {problem}")
    if args.no_gap:
        cfg.gap = False
    with output_dir(args.out, force=args.force, command="study") as tmp:
        out = run_study(cfg, tmp, workers=args.workers, scheduler=args.scheduler)
    report = str(out.report).replace(str(tmp.resolve()), str(args.out))
    n_bad = sum(1 for r in out.results if not r.get("ok"))
    print(f"{len(out.results)} session(s), {n_bad} failed, {out.elapsed_s:.1f} s "
          f"({out.mode}); report: {report}")
    return 1 if n_bad else 0
