"""The handlers of ``nmsid control design`` and ``nmsid control report``."""

from __future__ import annotations

import argparse
from pathlib import Path

from nmsid.analysis.control.design import design_controller, design_report
from nmsid.analysis.control.errors import TrackingReportError
from nmsid.analysis.control.report import report_markdown, write_report
from nmsid.analysis.twin import Twin
from nmsid.cli.errors import UsageError
from nmsid.protocols.output_paths import check_output, output_dir
from nmsid.protocols.session_file import read_session


def design(args: argparse.Namespace) -> int:
    check_output(args.out, force=args.force, kind="folder")
    twin = Twin.load(args.twin)
    d = design_controller(twin, sE=args.sE, update_Hz=args.update_hz,
                          lambda_s=args.lambda_s, learning_gain=args.learning_gain)
    with output_dir(args.out, force=args.force, command="control design") as tmp:
        d.save(tmp / "controller.json")
        (tmp / "design.md").write_text(design_report(d), encoding="utf-8")
    lv = min(d.levels, key=lambda x: abs(x.sE - d.sE))
    gm = lv.margins["gain_margin"]
    print(f"controller for {d.participant or 'participant'} at sE {d.sE:.3f}: Kc {d.Kc:.4g} "
          f"{d.per_unit}, Ti {1000 * d.Ti_s:.1f} ms; margins GM "
          f"{'inf' if gm is None else format(gm, '.2f')}, PM "
          f"{lv.margins['phase_margin_deg']:.1f} deg; targets "
          f"{d.force_range_N[0]:.2f}..{d.force_range_N[1]:.2f} {d.measured_unit}", flush=True)
    print(f"written to {args.out} (controller.json, design.md)", flush=True)
    return 0


def report(args: argparse.Namespace) -> int:
    """One session: its report in ``--out``. Several: one sub-folder per session name."""
    paths = list(dict.fromkeys(args.session))  # a file named twice is reported once
    stems = [Path(p).stem for p in paths]
    twice = next((s for s in stems if stems.count(s) > 1), None)
    if twice:
        raise UsageError(f"two sessions are named {twice}.h5 (in different folders); report "
                         "them one at a time with their own --out")
    check_output(args.out, force=args.force, kind="folder")
    sessions = [read_session(p) for p in paths]  # every file read before anything is written
    if len(sessions) > 1:  # a glob: the sessions without tracking trials are named, skipped
        tracking = [any(t.extra_attrs.get("trial_kind") == "tracking" for t in s.trials)
                    for s in sessions]
        for p, ok in zip(paths, tracking, strict=True):
            if not ok:
                print(f"{p}: skipped: no tracking trials (not a session of nmsid run "
                      "--track)", flush=True)
        if not any(tracking):
            raise TrackingReportError(f"none of the {len(paths)} sessions has tracking "
                                      "trials (sessions of nmsid run --track)")
        sessions = [s for s, ok in zip(sessions, tracking, strict=True) if ok]
        stems = [st for st, ok in zip(stems, tracking, strict=True) if ok]
    with output_dir(args.out, force=args.force, command="control report") as tmp:
        reps = []
        for session, stem in zip(sessions, stems, strict=True):
            where = Path(tmp) if len(sessions) == 1 else Path(tmp) / stem
            where.mkdir(exist_ok=True)
            reps.append(write_report(session, where))
    for rep, stem in zip(reps, stems, strict=True):
        print(report_markdown(rep).split("\n\n")[1], flush=True)
        where = Path(args.out) if len(reps) == 1 else Path(args.out) / stem
        print(f"written to {where} (tracking.json, report.md, figures/)", flush=True)
    return 0
