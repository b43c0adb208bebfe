"""``nmsid export nwb SESSION.h5 --out SESSION.nwb``: share a session as NWB;
``nmsid export fmu TWIN.json --out P01.fmu``: a twin as an FMU (the same as ``nmsid twin
export TWIN.json --fmu``)."""

from __future__ import annotations

from nmsid.cli.arguments import input_file, iso_age, non_empty_text, output_path
from nmsid.cli.identify import add_fmu_export_arguments


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    p = sub.add_parser("export", help="export a session file (NWB) or a twin (FMU) to "
                                      "another format")
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
    f = fmt.add_parser("fmu", help="write a twin file as an FMI 2.0 FMU (co-simulation + "
                       "model exchange); the same as `nmsid twin export TWIN.json --fmu`",
                       description="Write a twin file (one joint, or several: one FMU with "
                                   "rE_<joint>, sE_<joint> in and each joint's force or "
                                   "torque out) as a Functional Mock-up Unit, FMI 2.0: C "
                                   "sources plus a binary for this platform built with the "
                                   "system's C compiler. See docs/fmu.md.")
    add_fmu_export_arguments(f, fmu_flag=False)
    p.set_defaults(handler="nmsid.cli.export_command:run_missing_format")
