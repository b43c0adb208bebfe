"""Handlers of ``nmsid export`` (registered by :mod:`nmsid.cli.export`; pynwb loads here)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nmsid.cli.errors import UsageError
from nmsid.export.nwb import export_nwb, inspect_nwb
from nmsid.progress import Progress
from nmsid.protocols.output_paths import check_output, output_dir, output_file


def run_missing_format(args) -> int:
    raise UsageError("say which format to export to: `nmsid export nwb SESSION.h5 --out "
                     "SESSION.nwb` or `nmsid export fmu TWIN.json --out P01.fmu`")


def run_nwb(args) -> int:
    sessions = list(dict.fromkeys(args.session))  # a file named twice is written once
    if len(sessions) == 1:
        check_output(args.out, force=args.force, kind="file")
        with output_file(args.out, force=args.force) as tmp:
            # export_nwb never overwrites: it writes the new file at `tmp` (absent), which
            # replaces --out only once it is complete
            result = _export(args, sessions[0], tmp)
        results = [dataclasses.replace(result, path=Path(args.out))]
    else:
        if Path(args.out).suffix.lower() == ".nwb":
            raise UsageError(f"--out {args.out}: {len(sessions)} sessions give one NWB file "
                             "each; give a folder for them (e.g. --out nwb/)")
        stems = [Path(s).stem for s in sessions]
        twice = next((s for s in stems if stems.count(s) > 1), None)
        if twice:
            raise UsageError(f"two sessions are named {twice}.h5 (in different folders); "
                             "export them one at a time with their own --out")
        check_output(args.out, force=args.force, kind="folder")
        results = []
        with output_dir(args.out, force=args.force, command="export nwb") as tmp, \
                Progress(len(sessions), f"export nwb: {len(sessions)} sessions",
                         unit="session") as bar:
            for s, stem in zip(sessions, stems, strict=True):
                results.append(_export(args, s, Path(tmp) / f"{stem}.nwb"))
                bar.update()
        results = [dataclasses.replace(r, path=Path(args.out) / f"{stem}.nwb")
                   for r, stem in zip(results, stems, strict=True)]
    for result in results:
        print(f"{result.path}: {result.n_trials} trial(s), {result.n_series} time series, "
              f"{result.n_events} event(s)")
        if args.inspect:
            findings = inspect_nwb(result.path)
            for m in findings:
                print(f"  nwbinspector {m.importance.name}: {m.check_function_name} at "
                      f"{m.location}: {m.message}")
            print(f"  nwbinspector: {len(findings)} finding(s)")
    return 0


def _export(args, session, path):
    return export_nwb(session, path, subject_age=args.subject_age,
                      experimenter=args.experimenter, institution=args.institution)
