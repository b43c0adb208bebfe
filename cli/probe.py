"""``nmsid probe --hw-config FILE``: list and check the configured devices, never stimulate.

For each device of the hardware configuration, ON ITS OWN: connect, print what it reports
(model, serial, firmware, current range and resolution, channels, rate), take a few force
samples with a software-started acquisition, read the E-stop switch, and release it. The
stimulator is connected and queried only: nothing is downloaded or started. A device that
cannot be reached (missing library, unplugged cable) is one line ``<device>: FAILED:
<reason>`` and the others are still checked; exit status 1 if any failed (2 for a bad
configuration file).

Registration only (argparse); the handler is in :mod:`nmsid.cli.probe_command`.
"""

from __future__ import annotations

from nmsid.cli.arguments import bounded_int


def register(sub) -> None:
    p = sub.add_parser("probe", help="list and check the configured hardware (no stimulation)",
                       description="Connect to each device of the hardware configuration, "
                       "print what it reports and a few force samples, then release it. "
                       "Nothing is stimulated.")
    p.add_argument("--hw-config", metavar="FILE",
                   help="the rig's hardware configuration (TOML); needed except for "
                   "--check-assembly DLL")
    p.add_argument("--samples", type=bounded_int(1, 10_000, " (the probe reads for at most "
                                                    "5 s)"), default=20, metavar="N",
                   help="force samples to read, 1 ... 10000 (default 20)")
    p.add_argument("--dry-run", action="store_true",
                   help="also run one short low-current trial into a dummy-load resistor "
                   "and check the recorded current against the command (docs/hardware.md)")
    p.add_argument("--load-ohm", type=float, default=1000.0, metavar="OHM",
                   help="dry run: the dummy-load resistor (default 1000)")
    p.add_argument("--dry-run-channel", choices=("extensor", "flexor"), default="extensor",
                   help="dry run: the STG channel wired to the resistor (default extensor)")
    p.add_argument("--dry-run-mA", type=float, default=2.0, metavar="MA",
                   help="dry run: peak current, at most 5 mA (default 2)")
    p.add_argument("--check-assembly", nargs="?", const="", default=None, metavar="DLL",
                   help="only check that McsUsbNet.dll (DLL, else the hardware file's "
                   "stimulator.dll_path) has every member the STG driver uses, with its "
                   "argument types; touches no device and needs no hardware file")
    p.set_defaults(handler="nmsid.cli.probe_command:probe")
