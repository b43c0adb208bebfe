"""The handler of ``nmsid validate`` (registered by :mod:`nmsid.cli.validate`)."""

from __future__ import annotations

from nmsid.protocols.session_file import validate_session


def run(args) -> int:
    """Print every contract violation of each file; exit 1 if any file is invalid."""
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
