"""``nmsid stimulation``: what the configured stimulator would deliver, per sE level, without
hardware.

Registration only (argparse); the handler is in :mod:`nmsid.cli.stimulation_command`.
"""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser(
        "stimulation", help="render every sE level as the STG4002 driver would download it "
        "and report currents and charges (no hardware)",
        description="Render every sE level of the protocol exactly as the STG4002 driver "
        "would download it (same code path) and write DIR/stimulation.json (per channel: "
        "peak current, charge per phase, worst net charge per carrier period, net charge "
        "per trial, points, memory) and DIR/samples.npz (current samples in nA at the "
        "output rate, one trial per level and channel). For a pulse stimulator "
        "([stimulator] kind = \"rehastim2\") the same per level: the current of each "
        "pulse, peak current and charge per phase. No device is used.")
    p.add_argument("--config", metavar="TOML", default=None,
                   help="protocol configuration (default: the built-in paper protocol)")
    p.add_argument("--calibration", metavar="Iemin,Iemax,Ifmin,Ifmax", required=True,
                   help="the four calibration currents in mA, e.g. 2,16,1.5,16")
    p.add_argument("--hw-config", metavar="TOML", default=None,
                   help="the rig's hardware configuration (channels, ceilings, output rate); "
                   "default: an STG4002 with 16 mA ceilings")
    p.add_argument("--out", metavar="DIR", required=True,
                   help="output folder (must not exist unless --force)")
    p.add_argument("--force", action="store_true",
                   help="write into an existing --out (replaces its stimulation.json and "
                   "samples.npz only)")
    p.set_defaults(handler="nmsid.cli.stimulation_command:run")
