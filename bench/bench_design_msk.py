"""The designed protocol against the paper's on musculoskeletal participants (issue 13).

The template participants of ``bench_design`` are second-order by construction; MyoSuite's
MuJoCo elbow under FES (``sim_backends.msk_participant``) is not. Here both protocols (the
paper's 15 x 3 x (5 s + 10 s chirp), and the proposal of ``bench_design``: 15 x 3 x (2 s
+ 4 s chirp), 40 % of the stimulation) run on the same musculoskeletal participants and
are identified the same way (QC on). Reference: the participant's best second-order
description of its noise-free response to the paper's trial (``second_order_truth``, what
a lab's twin from the paper's protocol is meant to be). Printed: per protocol, the RMS
and max relative error of Kp, wn, zeta over levels and participants, the fit % reached,
and the proposal's parameters against the paper protocol's own estimates.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from analysis.design.candidates import Candidate, paper_candidate  # noqa: E402
from analysis.design.validate import simulate_session  # noqa: E402
from analysis.identify import identify_session  # noqa: E402

PROPOSAL = Candidate(steady_s=2.0, chirp_s=4.0, rest_s=24.0, label="proposal")


def main(n_participants: int = 3) -> None:
    try:
        from sim_backends.msk_population import make_msk_population  # mujoco extra
    except ImportError as exc:
        print(f"musculoskeletal participant unavailable ({exc}); install the mujoco extra")
        return
    t0 = time.perf_counter()
    people = make_msk_population(n_participants, seed=7)
    paper = paper_candidate()
    rows = {"paper": [], "proposal": [], "proposal_vs_paper": []}
    fits = {"paper": [], "proposal": []}
    for k, vp in enumerate(people):
        cal = vp.ramp_calibration()
        est = {}
        for cand in (paper, PROPOSAL):
            res = identify_session(simulate_session(vp, cand, seed=k))
            est[cand.label] = {round(lv.sE, 6): (lv.fit.Kp, lv.fit.wn_rad_s, lv.fit.zeta)
                               for lv in res.levels if lv.fit is not None}
            fits[cand.label] += [lv.fit.fit_pct for lv in res.levels if lv.fit is not None]
        for sE in paper.sE_levels:
            truth = vp.second_order_truth(sE, cal, paper.config().protocol)
            ref = np.array([truth.Kp, truth.wn_rad_s, truth.zeta])
            for label in ("paper", "proposal"):
                if sE in est[label]:
                    rows[label].append(np.array(est[label][sE]) / ref - 1)
            if sE in est["paper"] and sE in est["proposal"]:
                rows["proposal_vs_paper"].append(np.array(est["proposal"][sE]) /
                                                 np.array(est["paper"][sE]) - 1)
    print(f"{n_participants} musculoskeletal participants (population seed 7), 15 levels each; "
          "reference: best second-order description of the paper's trial")
    print(f"{'protocol':22s} {'stim s':>6s}  RMS |rel. error| % (Kp, wn, zeta)   "
          "max % (Kp, wn, zeta)       fit %")
    for label, cand in (("paper", paper), ("proposal", PROPOSAL)):
        e = np.abs(np.array(rows[label])) * 100
        f = fits[label]
        print(f"{label:22s} {cand.stimulation_s:6.0f}  "
              f"{np.round(np.sqrt(np.mean(e ** 2, axis=0)), 3).tolist()!s:30s} "
              f"{np.round(e.max(axis=0), 3).tolist()!s:26s} {min(f):.1f}-{max(f):.1f}")
    d = np.abs(np.array(rows["proposal_vs_paper"])) * 100
    print(f"{'proposal vs paper est.':22s} {'':6s}  "
          f"{np.round(np.sqrt(np.mean(d ** 2, axis=0)), 3).tolist()!s:30s} "
          f"{np.round(d.max(axis=0), 3).tolist()!s:26s}")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
