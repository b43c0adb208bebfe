"""Handler of ``nmsid qc`` (registered by :mod:`nmsid.cli.qc`)."""

from __future__ import annotations

from nmsid.analysis.data_bounds import check_session_data
from nmsid.analysis.qc import assess_session
from nmsid.analysis.qc.table import as_json, format_table
from nmsid.protocols.session_file import read_session


def run(args) -> int:
    """Print each session's QC table (or JSON); 1 if any trial is excluded."""
    any_excluded = False
    for path in args.sessions:
        session = read_session(path)  # read once: checked, then judged
        check_session_data(session, path)  # absurd values: one line
        qc = assess_session(session)
        print(as_json(qc) if args.json else format_table(qc, all_trials=args.all))
        any_excluded |= bool(qc.excluded())
    return 1 if any_excluded else 0
