"""The handlers of ``nmsid control design`` and ``nmsid control report``."""

from __future__ import annotations

import argparse

from nmsid.analysis.control.design import design_controller, design_report
from nmsid.analysis.control.report import report_markdown, write_report
from nmsid.analysis.twin import Twin
from nmsid.protocols.output_paths import check_output, output_dir
from nmsid.protocols.session_file import read_session


def design(args: argparse.Namespace) -> int:
    check_output(args.out, force=args.force, kind="folder")
    twin = Twin.load(args.twin)
    d = design_controller(twin, sE=args.sE, update_Hz=args.update_hz,
                          lambda_s=args.lambda_s, learning_gain=args.learning_gain)
    with output_dir(args.out, force=args.force) as tmp:
        d.save(tmp / "controller.json")
        (tmp / "design.md").write_text(design_report(d), encoding="utf-8")
    lv = min(d.levels, key=lambda x: abs(x.sE - d.sE))
    gm = lv.margins["gain_margin"]
    print(f"controller for {d.participant or 'participant'} at sE {d.sE:.3f}: Kc {d.Kc:.4g} "
          f"rE/N, Ti {1000 * d.Ti_s:.1f} ms; margins GM "
          f"{'inf' if gm is None else format(gm, '.2f')}, PM "
          f"{lv.margins['phase_margin_deg']:.1f} deg; targets "
          f"{d.force_range_N[0]:.2f}..{d.force_range_N[1]:.2f} N", flush=True)
    print(f"written to {args.out} (controller.json, design.md)", flush=True)
    return 0


def report(args: argparse.Namespace) -> int:
    check_output(args.out, force=args.force, kind="folder")
    session = read_session(args.session)
    with output_dir(args.out, force=args.force) as tmp:
        rep = write_report(session, tmp)
    print(report_markdown(rep).split("\n\n")[1], flush=True)
    print(f"written to {args.out} (tracking.json, report.md, figures/)", flush=True)
    return 0
