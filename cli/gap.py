"""``nmsid gap``: where the simulation misses, which unmodelled effect explains it, and how
far adding that effect shrinks the gap on held-out trials.

    nmsid gap SESSION.h5 [SESSION.h5 ...] --out DIR [--twin TWIN.json | --sim-session SIM.h5]

Registration only (argparse); the handler is in :mod:`nmsid.cli.gap_command`.
"""

from __future__ import annotations

from nmsid.cli.arguments import folder_to_write, input_file


def register(sub) -> None:
    """Add the ``gap`` sub-command."""
    p = sub.add_parser(
        "gap", help="diagnose the sim-to-real gap (where, which effect, how far it shrinks)",
        description="Fit the nominal twin (second order per sE) and its augmentation by "
                    "each registered candidate effect (nmsid.protocols.effects; listed in "
                    "docs/gap.md) on training repeats, score them on held-out repeats (3-fold "
                    "cross-validation by repeat) and by an information criterion with the "
                    "effective number of samples, localise the gap, and write "
                    "gap_report.json, report.html with figures, and the augmented twin.json. "
                    "See docs/gap.md.")
    p.add_argument("sessions", nargs="+", metavar="SESSION.h5", type=input_file,
                   help="session file(s)")
    p.add_argument("--out", required=True, metavar="DIR", type=folder_to_write,
                   help="output folder")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out folder (atomically; never one holding "
                        "a session file)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--twin", metavar="TWIN.json", type=input_file,
                     help="simulation under test: this twin file instead of the nominal "
                          "twin fitted on the training trials (used for the 'where' part)")
    src.add_argument("--sim-session", metavar="SIM.h5", type=input_file,
                     help="simulation under test: a simulated session (trials matched by "
                          "sE and repeat)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-pairs", action="store_true",
                   help="do not try the winner together with a second effect")
    p.add_argument("--no-muscle", action="store_true",
                   help="do not try the physiological (muscle) twin when the template "
                        "leaves a significant gap (it adds about a minute per session)")
    p.add_argument("--all-candidates", action="store_true",
                   help="fit and rank every candidate even when the nominal model's gap is "
                        "within noise (by default they are then skipped: none of them could "
                        "change the verdict 'none')")
    p.add_argument("--ic-margin", type=float, default=10.0, metavar="D",
                   help="an effect needs dIC below -D (default 10)")
    p.add_argument("--min-shrink-pct", type=float, default=10.0, metavar="P",
                   help="an effect must cut the held-out NRMSE by P %% (default 10)")
    p.set_defaults(handler="nmsid.cli.gap_command:run")
