"""Handler of ``nmsid design`` (registered by :mod:`nmsid.cli.design`)."""

from __future__ import annotations

import argparse

from nmsid.analysis.design.api import run_design
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.prior import (adequacy_from_parameters, population_prior,
                                         scatter_from_parameters, twin_prior)


def run(args: argparse.Namespace) -> int:
    """Handler of ``nmsid design``."""
    for name in ("n_prior", "validate"):
        v = getattr(args, name)
        if v < (1 if name == "n_prior" else 0):
            raise DesignError(f"--{name.replace('_', '-')} {v}: give a whole number >= "
                              f"{1 if name == 'n_prior' else 0}")
    if not 0 <= args.tolerance < 1:
        raise DesignError(f"--tolerance {args.tolerance:g}: a fraction in [0, 1)")
    if not 0 <= args.min_steady_s <= 60:
        raise DesignError(f"--min-steady-s {args.min_steady_s:g}: seconds in [0, 60]")
    if args.twin:
        prior = twin_prior(args.twin, args.noise_N)
    else:
        prior = population_prior(args.n_prior, args.seed)
    scatter = args.scatter
    if args.scatter_from:
        if not args.twin:
            raise DesignError("--scatter-from needs --twin (the curves the scatter is "
                              "measured about)")
        scatter = scatter_from_parameters(args.scatter_from, prior)
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
    doc = run_design(prior, args.target, args.out, validate_n=args.validate,
                     scatter=scatter, tolerance=args.tolerance,
                     min_steady_s=args.min_steady_s, seed=args.seed, twin_path=args.twin,
                     population_seed=args.seed, keep_paper_excitation=keep,
                     excitation_note=note)
    v = doc["validated_sd_ratio"]
    print(f"{args.out}/protocol.toml: {doc['protocol_description']}")
    print(f"stimulation {doc['stimulation_s']:g} s = {100 * doc['stimulation_fraction']:.0f} % "
          f"of the paper's {doc['paper_stimulation_s']:g} s; session "
          f"{doc['session_s'] / 60:.1f} min vs {doc['paper_session_s'] / 60:.1f} min")
    print(f"predicted_sd_ratio {doc['predicted_sd_ratio']:.4f}; validated_sd_ratio "
          + ("not run" if v is None else f"{v:.4f}")
          + f"; selection accuracy (predicted) {doc['selection_accuracy']['proposal']:.3f} "
          f"vs paper {doc['selection_accuracy']['paper']:.3f}")
    if not doc["found"]:
        print("no candidate met the target; this is the closest (see report.txt)")
    return 0
