"""The handler of ``nmsid validate`` (registered by :mod:`nmsid.cli.validate`)."""

from __future__ import annotations

import sys

from nmsid.errors import EXIT_USER_ERROR
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.protocols.session_lock import live_writer


def run(args) -> int:
    """Print every contract violation of each file; exit 2 (a bad file: a user error, with
    one line on stderr) if any file is invalid.

    A file that a run is writing now is checked as published so far (the writer
    publishes whole new versions atomically, so that is a consistent snapshot) and the
    output says so, naming the writer.
    """
    bad = 0
    for path in args.files:
        warnings: list[str] = []
        problems = validate_session(path, warnings=warnings)
        writer = live_writer(path)
        live = ""
        if writer is not None:
            live = f" (live session: written now by {writer.describe()}; checked as published " \
                   "so far)"
        if problems:
            bad += 1
            print(f"{path}: INVALID ({len(problems)} problem(s)){live}")
            for p in problems:
                print(f"  - {p}")
        else:
            n = _n_trials(path)
            print(f"{path}: valid nmsid session file (format version 1){live}"
                  + (f"; {n} trial(s) so far" if live and n is not None else "")
                  + (f"; {len(warnings)} warning(s)" if warnings else ""))
        for w in warnings:  # implausible but allowed by the contract: read and analysed
            print(f"  warning: {w}")
    if bad:
        print(f"nmsid: error: {bad} of {len(args.files)} file(s) invalid (see above)",
              file=sys.stderr)
        return EXIT_USER_ERROR
    return 0


def _n_trials(path) -> int | None:
    try:
        return len(read_session(path, load_data=False).trials)
    except (ValueError, OSError):
        return None
