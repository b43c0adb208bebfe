"""``nmsid design``: the least stimulation for a twin of a given precision.

    nmsid design (--twin TWIN.json | --population) [--target paper|SD-spec] --out DIR

Registration only (argparse); the handler is in :mod:`nmsid.cli.design_command`.
"""

from __future__ import annotations

import argparse

from nmsid.cli.arguments import seed


def _scatter(text: str) -> dict:
    out = {}
    for part in text.split(","):
        name, sep, value = part.partition("=")
        name = {"wn": "wn_rad_s"}.get(name.strip(), name.strip())
        if not sep or name not in ("Kp", "wn_rad_s", "zeta"):
            raise argparse.ArgumentTypeError(
                f"{text!r}: give Kp=F,wn_rad_s=F,zeta=F (relative SDs per trial, e.g. "
                "Kp=0.1,wn_rad_s=0.05,zeta=0.05)")
        try:
            out[name] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name}={value!r} is not a number") from None
        if not 0 <= out[name] < 1:
            raise argparse.ArgumentTypeError(f"{name}={out[name]:g}: a relative SD in [0, 1)")
    return out


def register(sub) -> None:
    """Add the ``design`` sub-command."""
    p = sub.add_parser(
        "design", help="design a protocol with less stimulation (Cramer-Rao bound + "
                       "simulation)",
        description="For a prior twin (a participant's twin.json from a first short session, "
                    "or the simulator's population), predict the Cramer-Rao bound of Kp, wn, "
                    "zeta per sE, of their curves over sE and of the AICc model choice for "
                    "candidate protocols (excitation length, band, amplitude, chirp or "
                    "multisine, sE levels, repeats, rests); propose the one with the least "
                    "stimulation that meets the target, validate it against the paper's "
                    "protocol on simulated participants, and write protocol.toml (for "
                    "nmsid run --config / nmsid gui), design.json, report.txt/.html and a "
                    "figure.")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--twin", metavar="TWIN.json", help="prior: one participant's twin")
    src.add_argument("--population", action="store_true",
                     help="prior: the simulator's population")
    p.add_argument("--target", default="paper",
                   help="'paper' (no worse than the paper's protocol) or relative SDs of "
                        "the curves, e.g. 'Kp=0.05,wn_rad_s=0.03,zeta=0.03'")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --out folder (atomically; never one holding "
                        "a session file)")
    p.add_argument("--noise-N", type=float, default=None, metavar="N",
                   help="sensor noise RMS for a --twin prior, in the twin's unit (default "
                        "0.04 N at the elbow, scaled by the joint's Fmax: 0.4 N m at the "
                        "knee, 0.16 N m at the ankle)")
    p.add_argument("--joint", default=None, metavar="JOINT",
                   help="with --population: the population of this joint (default elbow; "
                        "docs/joints.md); with --twin the twin's joint is used")
    sc = p.add_mutually_exclusive_group()
    sc.add_argument("--scatter", type=_scatter, default=None, metavar="SPEC",
                    help="per-trial physiological scatter, relative SDs (default "
                         "Kp=0.1,wn_rad_s=0.05,zeta=0.05; 0 for sensor noise only)")
    sc.add_argument("--scatter-from", metavar="PARAMETERS.csv",
                    help="with --twin: measure the scatter on the first session (the "
                         "parameters.csv nmsid identify wrote beside twin.json)")
    p.add_argument("--excitation", choices=("auto", "paper", "free"), default="auto",
                   help="auto (default): with --scatter-from, keep the paper's excitation "
                        "(10 s chirp 1-10 Hz, amplitude 0.5) when the first session is not "
                        "second order (median fit < 97 %%), since the twin then depends on "
                        "the input; paper: always keep it; free: search inputs regardless")
    p.add_argument("--n-prior", type=int, default=20, metavar="N",
                   help="population participants the design is computed for (default 20)")
    p.add_argument("--validate", type=int, default=10, metavar="N",
                   help="simulated participants for the validation (default 10; 0 skips)")
    p.add_argument("--min-steady-s", type=float, default=2.0, metavar="S",
                   help="shortest rE = 0.5 lead-in a candidate may have (default 2 s)")
    p.add_argument("--tolerance", type=float, default=0.02, metavar="F",
                   help="'no worse' allows standard errors this fraction above the paper's "
                        "(default 0.02)")
    p.add_argument("--seed", type=seed, default=0,
                   help="population and Monte-Carlo seed, 0 ... 2**63-1 (default 0)")
    p.set_defaults(handler="nmsid.cli.design_command:run")
