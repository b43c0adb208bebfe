"""``nmsid study STUDY.toml|FOLDER --out DIR [--workers N | --scheduler ADDRESS]``."""

from __future__ import annotations

import argparse

from nmsid.cli.arguments import folder_to_write, input_path


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= n <= 256:
        raise argparse.ArgumentTypeError(f"--workers {n}: use 0 (serial) to 256")
    return n


def register(sub) -> None:
    """Add the ``study`` sub-command."""
    p = sub.add_parser(
        "study", help="identify and diagnose many sessions as Dask tasks and write the "
        "group report",
        description="Every session's identification (as `nmsid identify`) and gap "
                    "diagnosis run as Dask tasks; then the group analysis (Tables 1-9, "
                    "Figures 4-6, the group gap summary) in DIR/report.html plus CSV/JSON. "
                    "A failing session is reported and the others go on. See docs/study.md.")
    p.add_argument("study", metavar="STUDY.toml|FOLDER", type=input_path)
    p.add_argument("--out", required=True, metavar="DIR", type=folder_to_write)
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out folder (atomically; never one holding "
                        "a session file)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_workers, default=2, metavar="N",
                       help="worker processes of the local Dask cluster (default 2; 0 = "
                            "serial in this process)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (workers "
                            "must see the files at the same paths)")
    p.add_argument("--no-gap", action="store_true", help="identification only")
    p.set_defaults(handler="nmsid.cli.study_command:run")
