"""``nmsid validate FILE ...``: check session files against the v1 contract."""

from __future__ import annotations
from protocols.session_file import validate_session


def register(sub) -> None:
    p = sub.add_parser("validate", help="check session files against the session-file "
                       "contract and print every violation")
    p.add_argument("files", nargs="+", metavar="FILE", help="session files (.h5)")
    p.set_defaults(handler="rig.cli_validate:run")


def run(args) -> int:

    bad = 0
    for path in args.files:
        problems = validate_session(path)
        if problems:
            bad += 1
            print(f"{path}: INVALID ({len(problems)} problem(s))")
            for p in problems:
                print(f"  - {p}")
        else:
            print(f"{path}: valid nmsid session file (format version 1)")
    return 1 if bad else 0
