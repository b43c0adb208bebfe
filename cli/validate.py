"""``nmsid validate FILE ...``: check session files against the v1 contract.

Registration only (argparse); the handler is in :mod:`nmsid.cli.validate_command`.
"""

from __future__ import annotations

from nmsid.cli.arguments import input_file


def register(sub) -> None:
    p = sub.add_parser("validate", help="check session files against the session-file "
                       "contract and print every violation")
    p.add_argument("files", nargs="+", metavar="FILE", type=input_file, help="session files (.h5)")
    p.set_defaults(handler="nmsid.cli.validate_command:run")
