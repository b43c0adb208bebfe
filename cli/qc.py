"""``nmsid qc``: the quality control's verdict on every trial of a session.

    nmsid qc SESSION.h5 [SESSION.h5 ...] [--json] [--all]

Registration only (argparse); the handler is in :mod:`nmsid.cli.qc_command`.
"""

from __future__ import annotations

from nmsid.cli.arguments import input_file


def register(sub) -> None:
    p = sub.add_parser(
        "qc", help="judge every trial (used / repaired / excluded, with reasons and spans)",
        description="Trial quality control: non-finite, stalled and clipped stretches, "
                    "spikes, baseline jumps, lead-in noise, and responses the other repeats "
                    "of the same sE do not share. Exit 0 when every trial is kept, 1 when "
                    "some are excluded, 2 for a file that cannot be read.")
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5", type=input_file)
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--all", action="store_true", help="list plainly used trials too")
    p.set_defaults(handler="nmsid.cli.qc_command:run")
