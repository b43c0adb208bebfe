"""Designed protocols against the paper's on musculoskeletal participants (issue 13).

The template participants of ``bench_design`` are second-order by construction; MyoSuite's
MuJoCo elbow under FES (``sim_backends.msk_participant``) is not: its best second-order
description depends on the input (a 4 s chirp gives wn about 0.25 % higher and zeta
0.3 % lower than the paper's 10 s chirp; the lead-in length changes nothing). So "the same
twin" is measured against one fixed reference, the participant's best second-order
description of its noise-free response to the PAPER's trial (``second_order_truth``, what
a lab's twin from the paper's protocol is meant to be), which favours the paper.

Two parts, each with and without per-trial physiological scatter (``DEFAULT_SCATTER``,
10 / 5 / 5 % on the physics behind Kp / wn / zeta: electrode reach, muscle and mount speed,
mount damping; ``MskParticipant.trial_variant``), the same draws per (sE, repeat) for
every protocol:

1. the population proposal of ``bench_design`` (15 x 3 x (2 s + 4 s chirp), 270 s, 40 %)
   and the paper's protocol with a 2 s lead-in (540 s);
2. the lab's own flow: a first session (5 levels x 2 repeats, the paper's trial) is
   identified, ``nmsid design --twin twin.json --scatter-from parameters.csv`` designs
   for it (keeping the paper's excitation when the first session's median fit is below
   97 %, as ``--excitation auto`` does), and the proposal and the paper's protocol then run
   on the participant.

Printed per protocol: stimulation seconds; RMS relative error against the reference of
the per-level estimates and of the twin's curves at the paper's 15 levels (the family
AICc picks on that protocol's own estimates), per parameter; ratios to the paper's.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from nmsid.analysis.curves import fit_curve  # noqa: E402
from nmsid.analysis.design.candidates import (  # noqa: E402
    Candidate,
    paper_candidate,
    search_space,
    with_paper_excitation,
)
from nmsid.analysis.design.predict import DEFAULT_SCATTER, Predictor  # noqa: E402
from nmsid.analysis.design.prior import (  # noqa: E402
    PARAMETERS,
    adequacy_from_parameters,
    scatter_from_parameters,
    twin_prior,
)
from nmsid.analysis.design.search import design, parse_target  # noqa: E402
from nmsid.analysis.design.validate import simulate_session  # noqa: E402
from nmsid.analysis.identify import identify_session  # noqa: E402
from nmsid.analysis.model_selection import compare_models  # noqa: E402
from nmsid.analysis.run import run_identification  # noqa: E402
from nmsid.analysis.settings import IdentificationSettings  # noqa: E402

if str(Path(__file__).resolve().parent) not in sys.path:   # bench/: workers
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from workers import importable, process_pool  # noqa: E402

GRID = paper_candidate().sE_levels
POPULATION_PROPOSAL = Candidate(steady_s=2.0, chirp_s=4.0, rest_s=24.0, label="proposal")
PAPER_SHORT_LEADIN = Candidate(steady_s=2.0, chirp_s=10.0, rest_s=48.0, label="2s-lead-in")
FIRST_SESSION = Candidate(sE_levels=(0.30, 0.45, 0.60, 0.80, 1.00), repeats=2,
                          label="first")


def reference_families(vp, reference: dict) -> list[str]:
    """Per parameter, the family AICc picks on the noise-free reference at the paper's
    15 levels: the family a twin of this participant should have."""
    settings = IdentificationSettings()
    ref = np.array([reference[round(s, 6)] for s in GRID])
    return [compare_models(np.array(GRID), ref[:, j], name, vp.code, settings).selected
            for j, name in enumerate(PARAMETERS)]


_RUNS: dict = {}
"""errors() of this process by (participant, protocol without its label, scatter, seed): a
protocol run twice with the same draws (part 2's paper protocol, a lab proposal equal to
a part-1 protocol) is simulated and identified once."""


def errors(vp, cand: Candidate, scatter, seed: int, reference: dict, families) -> dict:
    """Per-level and curve relative errors of ``cand`` on ``vp`` against ``reference``
    {sE: (Kp, wn, zeta)}; the curve is the reference's family fitted to the protocol's
    level estimates; ``right``: AICc on those estimates picks that family. Memoised
    (``_RUNS``): the same inputs give the same draws, so the same result."""
    key = (vp.code, repr({k: v for k, v in sorted(cand.__dict__.items()) if k != "label"}),
           repr(scatter), seed)
    if key not in _RUNS:
        _RUNS[key] = _errors(vp, cand, scatter, seed, reference, families)
    return _RUNS[key]


def _errors(vp, cand: Candidate, scatter, seed: int, reference: dict, families) -> dict:
    res = identify_session(simulate_session(vp, cand, scatter=scatter, seed=seed))
    lv = [(x.sE, (x.fit.Kp, x.fit.wn_rad_s, x.fit.zeta)) for x in res.levels
          if x.fit is not None]
    sE = np.array([s for s, _ in lv])
    est = np.array([v for _, v in lv])
    ref_lv = np.array([reference[round(s, 6)] for s in sE])
    ref_grid = np.array([reference[round(s, 6)] for s in GRID])
    curve = np.full((len(GRID), 3), np.nan)
    right = np.zeros(3, dtype=bool)
    settings = IdentificationSettings()
    for j, name in enumerate(PARAMETERS):
        fit = fit_curve(families[j], sE, est[:, j])
        if fit.coefficients is not None:
            curve[:, j] = np.asarray(fit.predict(np.array(GRID)))
        right[j] = compare_models(sE, est[:, j], name, vp.code, settings).selected \
            == families[j]
    return {"level": est / ref_lv - 1, "curve": curve / ref_grid - 1, "right": right}


def rms(rows: list, key: str) -> np.ndarray:
    e = np.concatenate([r[key] for r in rows], axis=0)
    return np.sqrt(np.nanmean(e ** 2, axis=0)) * 100


def lab_design(vp, scatter, seed: int) -> tuple[Candidate, dict, Any]:
    """What ``nmsid design --twin --scatter-from`` proposes after a first session."""
    with tempfile.TemporaryDirectory() as tmp:
        session = simulate_session(vp, FIRST_SESSION, scatter=scatter, seed=seed)
        run_identification([session], tmp, figures=False)
        prior = twin_prior(Path(tmp) / "twin.json", noise_N=float(vp.sensor.noise_N))
        measured = scatter_from_parameters(Path(tmp) / "parameters.csv", prior).to_dict()
        adequacy = adequacy_from_parameters(Path(tmp) / "parameters.csv")
    cands = search_space() if adequacy.second_order else with_paper_excitation(search_space())
    result = design(Predictor(prior, scatter=measured), parse_target("paper"), cands,
                    draws=50, seed=seed)
    return result.proposal.candidate, measured, adequacy


def selection(rows: list) -> float:
    return float(np.mean([r["right"] for r in rows]))


SCENARIOS = (("with physiological scatter 10/5/5 %", dict(DEFAULT_SCATTER)),
             ("without scatter (sensor noise only)", None))


def participant(args: tuple[int, int]) -> dict:
    """Everything one participant contributes (both scenarios, both parts): its reference,
    its families, its part-1 runs, the lab's design and its part-2 runs. A participant
    depends on its index only, so participants run in any process, in any order."""
    from nmsid.sim_backends.msk_population import make_msk_population
    k, n_participants = args
    vp = make_msk_population(n_participants, seed=7)[k]
    paper = paper_candidate()
    cal = vp.ramp_calibration()
    ref = {round(s, 6): tuple(vp.true_parameters(s, cal, paper.config().protocol))
           for s in GRID}
    fam = reference_families(vp, ref)
    out: dict = {"code": vp.code, "family": fam, "scenarios": []}
    for _, scatter in SCENARIOS:
        part1 = {cand.label: errors(vp, cand, scatter, 11 + k, ref, fam)
                 for cand in (paper, PAPER_SHORT_LEADIN, POPULATION_PROPOSAL)}
        prop, measured, adequacy = lab_design(vp, scatter, 500 + k)
        prop = Candidate(**{**prop.__dict__, "label": "lab"})
        # the same draws as part 1 (seed 11 + k): a proposal equal to a part-1 protocol,
        # and the paper's protocol, reuse part 1's runs (``errors``)
        out["scenarios"].append({
            "part1": part1, "proposal": prop, "measured": measured,
            "fit_pct": adequacy.median_fit_pct,
            "lab": errors(vp, prop, scatter, 11 + k, ref, fam),
            "paper": errors(vp, paper, scatter, 11 + k, ref, fam)})
    out["runs"] = len([key for key in _RUNS if key[0] == vp.code])
    return out


def main(n_participants: int = 4, jobs: int = 2) -> None:
    """``jobs`` worker processes, one participant at a time each (2: the bench machine's
    cores); the figures do not depend on it."""
    try:
        import nmsid.sim_backends.msk_population  # noqa: F401 - the mujoco extra
    except ImportError as exc:
        print(f"musculoskeletal participant unavailable ({exc}); install the mujoco extra")
        return
    t0 = time.perf_counter()
    _RUNS.clear()
    work = [(k, n_participants) for k in range(n_participants)]
    if jobs > 1:
        with process_pool(min(jobs, n_participants)) as ex:
            people = list(ex.map(importable(participant), work))
    else:
        people = [participant(w) for w in work]
    paper = paper_candidate()
    print(f"{n_participants} musculoskeletal participants (population seed 7); reference: "
          "each one's best second-order description of the paper's trial; families "
          f"(Kp, wn, zeta) by AICc on it: {[p['family'] for p in people]}")
    for i, (label, _) in enumerate(SCENARIOS):
        print(f"\n1. population proposal, {label}")
        print(f"  {'protocol':22s} {'stim s':>6s}  {'level RMS % (Kp, wn, zeta)':27s} "
              f"{'curve RMS % (Kp, wn, zeta)':27s} {'curve ratio to paper':22s} selection")
        rows = {cand.label: [p["scenarios"][i]["part1"][cand.label] for p in people]
                for cand in (paper, PAPER_SHORT_LEADIN, POPULATION_PROPOSAL)}
        base = rms(rows["paper"], "curve")
        for cand in (paper, PAPER_SHORT_LEADIN, POPULATION_PROPOSAL):
            r = rows[cand.label]
            what = f"{cand.steady_s:g}+{cand.chirp_s:g} s x{cand.repeats}"
            print(f"  {cand.label + ' ' + what:22s} {cand.stimulation_s:6.0f}  "
                  f"{np.round(rms(r, 'level'), 3).tolist()!s:27s} "
                  f"{np.round(rms(r, 'curve'), 3).tolist()!s:27s} "
                  f"{np.round(rms(r, 'curve') / base, 3).tolist()!s:22s} {selection(r):.3f}")
        print(f"\n2. the lab's flow (first session 5 x 2 -> design -> run), {label}; the "
              "protocols run with part 1's draws (a protocol already run there is reused)")
        print(f"  {'participant':11s} {'scatter measured':22s} {'fit %':>6s} "
              f"{'proposal':30s} {'stim s':>6s}")
        for p in people:
            sc = p["scenarios"][i]
            prop, measured = sc["proposal"], sc["measured"]
            m = [round(measured[n], 3) for n in PARAMETERS]
            what = (f"{len(prop.sE_levels)} lv x{prop.repeats}, {prop.steady_s:g}+"
                    f"{prop.chirp_s:g} s {prop.input_kind} {prop.chirp_f0_Hz:g}-"
                    f"{prop.chirp_f1_Hz:g} Hz")
            print(f"  {p['code']:11s} {m!s:22s} {sc['fit_pct']:6.1f} {what:30s} "
                  f"{prop.stimulation_s:6.0f}")
        prop_rows = [p["scenarios"][i]["lab"] for p in people]
        paper_rows = [p["scenarios"][i]["paper"] for p in people]
        a, b = rms(prop_rows, "curve"), rms(paper_rows, "curve")
        la, lb = rms(prop_rows, "level"), rms(paper_rows, "level")
        print(f"  level RMS %: designed {np.round(la, 3).tolist()} vs paper "
              f"{np.round(lb, 3).tolist()}, ratio {np.round(la / lb, 3).tolist()}")
        print(f"  curve RMS %: designed {np.round(a, 3).tolist()} vs paper "
              f"{np.round(b, 3).tolist()}, ratio {np.round(a / b, 3).tolist()}; selection "
              f"{selection(prop_rows):.3f} vs {selection(paper_rows):.3f}")
    print(f"\n({time.perf_counter() - t0:.0f} s, {jobs} worker process(es); "
          f"{sum(p['runs'] for p in people)} protocol runs simulated and identified)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 4)
