"""The handler of ``nmsid validate`` (registered by :mod:`nmsid.cli.validate`)."""

from __future__ import annotations

import sys

from nmsid.errors import EXIT_USER_ERROR
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.protocols.session_state import session_state
from nmsid.rig.recovery import clean_leftovers_if_idle


def run(args) -> int:
    """Print every contract violation of each file; exit 2 (a bad file: a user error, with
    one line on stderr) if any file is invalid.

    A file that a run is writing now is checked as published so far (a consistent
    snapshot: the writer publishes whole versions atomically) and the output says so,
    naming the writer and how many trials its journal holds. A valid file beside a journal
    with more trials (a killed session not yet recovered) is called incomplete. Leftovers
    of an interrupted end (``.journal.done-<pid>``, temp files) are removed when nobody
    writes the session, and named.
    """
    bad = 0
    for path in args.files:
        warnings: list[str] = []
        problems = validate_session(path, warnings=warnings)
        removed = clean_leftovers_if_idle(path)
        state = session_state(path)
        note = state.describe()
        note = f" ({note})" if note else ""
        if problems:
            bad += 1
            print(f"{path}: INVALID ({len(problems)} problem(s)){note}")
            for p in problems:
                print(f"  - {p}")
        else:
            n = _n_trials(path)
            label = {"live": "valid nmsid session file (format version 1), LIVE",
                     "incomplete": "valid nmsid session file (format version 1) but "
                                   "INCOMPLETE"}.get(state.label,
                                                     "valid nmsid session file (format "
                                                     "version 1)")
            print(f"{path}: {label}{note}"
                  + (f"; {n} trial(s) in the file" if state.label != "finished"
                     and n is not None else "")
                  + (f"; {len(warnings)} warning(s)" if warnings else ""))
        for w in warnings:  # implausible but allowed by the contract: read and analysed
            print(f"  warning: {w}")
        if removed:
            print(f"{path}: removed leftovers of an interrupted end: {', '.join(removed)}")
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
