"""Handler of ``nmsid design`` (registered by :mod:`nmsid.cli.design`)."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from nmsid.analysis.design.api import run_design
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.prior import (
    adequacy_from_parameters,
    population_prior,
    scatter_from_parameters,
    twin_prior,
)
from nmsid.protocols.joints import JOINTS
from nmsid.protocols.output_paths import check_output, output_dir

#: Largest --n-prior / --validate (each simulated participant costs a design evaluation).
COUNT_MAX = 1000
#: Largest --noise-N: a sensor noise RMS above 10 N would drown any wrist force.
NOISE_MAX_N = 10.0


def run(args: argparse.Namespace) -> int:
    """Handler of ``nmsid design``."""
    for name, lo in (("n_prior", 1), ("validate", 0)):
        v = getattr(args, name)
        if not lo <= v <= COUNT_MAX:
            raise DesignError(f"--{name.replace('_', '-')} {v}: give a whole number in "
                              f"[{lo}, {COUNT_MAX}]")
    if args.noise_N is not None and not (math.isfinite(args.noise_N)
                                         and 0 < args.noise_N <= NOISE_MAX_N):
        raise DesignError(f"--noise-N {args.noise_N:g}: a sensor noise RMS in (0, "
                          f"{NOISE_MAX_N:g}] N (or N m)")
    joint = getattr(args, "joint", None)
    if joint is not None and joint not in JOINTS:
        raise DesignError(f"--joint {joint!r}: valid: {', '.join(JOINTS)}")
    if not 0 <= args.tolerance < 1:
        raise DesignError(f"--tolerance {args.tolerance:g}: a fraction in [0, 1)")
    if not 0 <= args.min_steady_s <= 60:
        raise DesignError(f"--min-steady-s {args.min_steady_s:g}: seconds in [0, 60]")
    check_output(args.out, force=args.force, kind="folder")  # before the search
    if args.twin:
        prior = twin_prior(args.twin, args.noise_N)
        if joint is not None and joint != prior.joint:
            raise DesignError(f"--joint {joint} with --twin {args.twin}: the twin is of the "
                              f"{prior.joint}; leave --joint out (the twin's joint is used)")
    else:
        prior = population_prior(args.n_prior, args.seed, joint=joint or "elbow")
    scatter = args.scatter
    if args.scatter_from:
        if not args.twin:
            raise DesignError("--scatter-from needs --twin (the curves the scatter is "
                              "measured about)")
        scatter = scatter_from_parameters(args.scatter_from, prior).to_dict()
        print("scatter measured on the first session: " + ", ".join(
            f"{k} {100 * v:.2g} %" for k, v in scatter.items()))
    keep, note = args.excitation == "paper", ""
    if args.excitation == "paper":
        note = "asked for (--excitation paper)"
    elif args.excitation == "auto" and args.scatter_from:
        adequacy = adequacy_from_parameters(args.scatter_from)
        keep, note = not adequacy.second_order, adequacy.sentence()
        print(note)
    elif args.excitation == "free":
        note = "searched as asked (--excitation free)"
    with output_dir(args.out, force=args.force, command="design") as tmp:
        outcome = run_design(prior, args.target, tmp, validate_n=args.validate,
                             scatter=scatter, tolerance=args.tolerance,
                             min_steady_s=args.min_steady_s, seed=args.seed,
                             twin_path=args.twin, population_seed=args.seed,
                             keep_paper_excitation=keep, excitation_note=note, progress=True)
    outcome = dataclasses.replace(outcome, out_dir=Path(args.out))
    doc = outcome.to_dict()
    v = doc["validated_sd_ratio"]
    print(f"{Path(args.out) / 'protocol.toml'}: {doc['protocol_description']}")
    print(f"stimulation {doc['stimulation_s']:g} s = {100 * doc['stimulation_fraction']:.0f} % "
          f"of the paper's {doc['paper_stimulation_s']:g} s; session "
          f"{doc['session_s'] / 60:.1f} min vs {doc['paper_session_s'] / 60:.1f} min")
    print(f"predicted_sd_ratio {doc['predicted_sd_ratio']:.4f}; validated_sd_ratio "
          + ("not run" if v is None else f"{v:.4f}")
          + f"; selection accuracy (predicted) {doc['selection_accuracy']['proposal']:.3f} "
          f"vs paper {doc['selection_accuracy']['paper']:.3f}")
    if not doc["found"]:
        print("no candidate met the target; this is the closest (see report.txt)")
    print(outcome.verdict_line())
    return 0
