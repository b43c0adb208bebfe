"""``nmsid probe --hw-config FILE``: list and check the configured devices, never stimulate.

For each device of the hardware configuration: connect, print what it reports (model,
serial, firmware, current range and resolution, channels, rate), take a few force samples
with a software-started acquisition, read the E-stop switch, and release everything. The
stimulator is connected and queried only: nothing is downloaded or started. A missing
library or device ends in one line (exit status 2).

Registration only (argparse); the handler is in :mod:`nmsid.cli.probe_command`.
"""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("probe", help="list and check the configured hardware (no stimulation)",
                       description="Connect to each device of the hardware configuration, "
                       "print what it reports and a few force samples, then release it. "
                       "Nothing is stimulated.")
    p.add_argument("--hw-config", metavar="FILE", required=True,
                   help="the rig's hardware configuration (TOML)")
    p.add_argument("--samples", type=int, default=20, metavar="N",
                   help="force samples to read (default 20)")
    p.set_defaults(handler="nmsid.cli.probe_command:probe")
