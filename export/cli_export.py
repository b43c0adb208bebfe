"""``nmsid export nwb SESSION.h5 --out SESSION.nwb``: share a session as NWB."""

from __future__ import annotations


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    p = sub.add_parser("export", help="export a session file to another format (NWB)")
    fmt = p.add_subparsers(dest="export_format", metavar="FORMAT")
    n = fmt.add_parser("nwb", help="write the session as an NWB file (Neurodata Without "
                       "Borders); needs the extra 'nwb'",
                       description="Write one session as NWB: subject, devices, stimulus "
                                   "and acquisition series per trial, trials table, events, "
                                   "calibration and configuration. See README 'Sharing'.")
    n.add_argument("session", metavar="SESSION.h5")
    n.add_argument("--out", required=True, metavar="SESSION.nwb")
    n.add_argument("--subject-age", default="P18Y/", metavar="ISO8601",
                   help="participant age as an ISO 8601 duration or range (default P18Y/: "
                        "adult, exact age unknown; nmsid does not record age)")
    n.add_argument("--experimenter", action="append", default=None, metavar="NAME",
                   help="experimenter (repeatable; 'Last, First')")
    n.add_argument("--institution", default=None)
    n.add_argument("--inspect", action="store_true",
                   help="run nwbinspector on the result and print its findings")
    n.set_defaults(handler="export.cli_export:run_nwb")
    p.set_defaults(handler="export.cli_export:run_missing_format")


def run_missing_format(args) -> int:
    raise ValueError("say which format to export to: `nmsid export nwb SESSION.h5 --out "
                     "SESSION.nwb`")


def run_nwb(args) -> int:
    from export.nwb import export_nwb, inspect_nwb
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
