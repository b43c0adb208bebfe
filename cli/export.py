"""``nmsid export nwb SESSION.h5 --out SESSION.nwb``: share a session as NWB."""

from __future__ import annotations

from nmsid.cli.arguments import input_file, iso_age, non_empty_text, output_path


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    p = sub.add_parser("export", help="export a session file to another format (NWB)")
    fmt = p.add_subparsers(dest="export_format", metavar="FORMAT")
    n = fmt.add_parser("nwb", help="write the session as an NWB file (Neurodata Without "
                       "Borders); needs the extra 'nwb'",
                       description="Write each session as NWB: subject, devices, stimulus "
                                   "and acquisition series per trial, trials table, events, "
                                   "calibration and configuration. One session: --out is "
                                   "the .nwb file; several: --out is a folder receiving "
                                   "<session name>.nwb each. See docs/study.md.")
    n.add_argument("session", metavar="SESSION.h5", type=input_file, nargs="+")
    n.add_argument("--out", required=True, metavar="SESSION.nwb|DIR", type=output_path)
    n.add_argument("--force", action="store_true",
                   help="replace an existing --out (never a session file; a folder only "
                        "if nmsid wrote it)")
    n.add_argument("--subject-age", default="P18Y/", metavar="ISO8601", type=iso_age,
                   help="participant age as an ISO 8601 duration or range (default P18Y/: "
                        "adult, exact age unknown; nmsid does not record age)")
    n.add_argument("--experimenter", action="append", default=None, metavar="NAME",
                   type=non_empty_text,
                   help="experimenter (repeatable; 'Last, First')")
    n.add_argument("--institution", default=None)
    n.add_argument("--inspect", action="store_true",
                   help="run nwbinspector on the result and print its findings")
    n.set_defaults(handler="nmsid.cli.export_command:run_nwb")
    p.set_defaults(handler="nmsid.cli.export_command:run_missing_format")
