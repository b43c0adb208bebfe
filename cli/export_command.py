"""Handlers of ``nmsid export`` (registered by :mod:`nmsid.cli.export`; pynwb loads here)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nmsid.cli.errors import UsageError
from nmsid.export.nwb import export_nwb, inspect_nwb
from nmsid.protocols.output_paths import check_output, output_file


def run_missing_format(args) -> int:
    raise UsageError("say which format to export to: `nmsid export nwb SESSION.h5 --out "
                     "SESSION.nwb`")


def run_nwb(args) -> int:
    check_output(args.out, force=args.force, kind="file")
    with output_file(args.out, force=args.force) as tmp:
        # export_nwb never overwrites: it writes the new file at `tmp` (absent), which
        # replaces --out only once it is complete
        result = export_nwb(args.session, tmp, subject_age=args.subject_age,
                            experimenter=args.experimenter, institution=args.institution)
    result = dataclasses.replace(result, path=Path(args.out))
    print(f"{result.path}: {result.n_trials} trial(s), {result.n_series} time series, "
          f"{result.n_events} event(s)")
    if args.inspect:
        findings = inspect_nwb(result.path)
        for m in findings:
            print(f"  nwbinspector {m.importance.name}: {m.check_function_name} at "
                  f"{m.location}: {m.message}")
        print(f"  nwbinspector: {len(findings)} finding(s)")
    return 0
