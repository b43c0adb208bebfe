"""Handlers of ``nmsid export`` (registered by :mod:`nmsid.cli.export`; pynwb loads here)."""

from __future__ import annotations

from nmsid.export.nwb import export_nwb, inspect_nwb


def run_missing_format(args) -> int:
    raise ValueError("say which format to export to: `nmsid export nwb SESSION.h5 --out "
                     "SESSION.nwb`")


def run_nwb(args) -> int:
    result = export_nwb(args.session, args.out, subject_age=args.subject_age,
                        experimenter=args.experimenter, institution=args.institution)
    print(f"{result.path}: {result.n_trials} trial(s), {result.n_series} time series, "
          f"{result.n_events} event(s)")
    if args.inspect:
        findings = inspect_nwb(result.path)
        for m in findings:
            print(f"  nwbinspector {m.importance.name}: {m.check_function_name} at "
                  f"{m.location}: {m.message}")
        print(f"  nwbinspector: {len(findings)} finding(s)")
    return 0
