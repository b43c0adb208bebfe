"""How long the default ``nmsid design`` takes, against the default before issue 39.

The README's ``nmsid design --twin results/twin.json --out design/`` (default settings:
2400 candidates searched cheapest first, validation on 10 simulated participants, 2
protocols x 3 scatter models = 60 simulated sessions) took 8 min 14 s with no output before
issue 39, nearly all of it in the validation's identification of its 60 sessions with trial
quality control and per-repeat scatter fits. The validation now fits the levels only
(``analysis.design.validate.VALIDATION_SETTINGS``).

1. The default design end to end in this process, on a twin identified from one simulated
   session of the default participant: CPU seconds (this process, every thread) and wall
   seconds, with the machine's load.
2. The old default's time, estimated from the same run: its search and simulation time
   plus 60 x the CPU seconds of the old identification (QC and scatter fits on) of one
   validation session, measured on 3 sessions here (running the whole old default would
   cost ~7 CPU minutes of a shared machine). The target: at most 2 min on 2 cores.

    python bench/bench_design_speed.py
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(Path(__file__).resolve().parent) not in sys.path:   # bench/: cpu_time
    sys.path.insert(0, str(Path(__file__).resolve().parent))

from cpu_time import load_1min  # noqa: E402

from nmsid.analysis.design.api import run_design, validation_participants  # noqa: E402
from nmsid.analysis.design.candidates import paper_candidate  # noqa: E402
from nmsid.analysis.design.predict import DEFAULT_SCATTER  # noqa: E402
from nmsid.analysis.design.prior import twin_prior  # noqa: E402
from nmsid.analysis.design.validate import VALIDATION_SETTINGS, simulate_session  # noqa: E402
from nmsid.analysis.identify import identify_session  # noqa: E402
from nmsid.analysis.settings import IdentificationSettings  # noqa: E402
from nmsid.sim_backends.participant import default_participant  # noqa: E402

TARGET_S = 120.0
N_SESSIONS = 60  # the default validation: 10 participants x 2 protocols x 3 scatter models


def _twin(folder: Path) -> Path:
    path = folder / "twin.json"
    data = default_participant().to_twin()
    data["participant"] = "BENCH"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def _cpu(fn):
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="bench-design-") as tmp:
        folder = Path(tmp)
        twin = _twin(folder)
        prior = twin_prior(twin)
        la = load_1min()
        c0, w0 = time.process_time(), time.perf_counter()
        outcome = run_design(prior, "paper", folder / "out", twin_path=twin)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        print(f"1. default design (twin of the default participant, 10 validation "
              f"participants, {N_SESSIONS} sessions), load {la} -> {load_1min()}")
        print(f"   {cpu:.1f} CPU s, {wall:.1f} s wall; {outcome!r}")
        print(f"   {outcome.verdict_line()}")
        people, _ = validation_participants(prior, 3, twin_path=twin)
        sessions = [simulate_session(vp, paper_candidate(), scatter=dict(DEFAULT_SCATTER),
                                     seed=k) for k, vp in enumerate(people)]
        new = statistics.median(_cpu(lambda s=s: identify_session(
            s, VALIDATION_SETTINGS, trial_scatter=False)) for s in sessions)
        old = statistics.median(_cpu(lambda s=s: identify_session(
            s, IdentificationSettings())) for s in sessions)
        rest = max(0.0, cpu - N_SESSIONS * new)
        old_total = rest + N_SESSIONS * old
        print(f"2. identification of one validation session (paper protocol, median of 3): "
              f"{new:.2f} CPU s now (level fits) vs {old:.2f} CPU s before (QC + scatter "
              f"fits), {old / new:.1f}x")
        print(f"   old default estimated: {old_total:.0f} CPU s = {rest:.0f} s search and "
              f"simulation + {N_SESSIONS} x {old:.2f} s; now {cpu:.0f} CPU s "
              f"({old_total / cpu:.1f}x less)")
        verdict = "met" if cpu <= TARGET_S else "missed"
        print(f"   target: default design within {TARGET_S:.0f} s on 2 cores: {cpu:.0f} CPU s "
              f"on one core ({verdict}; wall {wall:.0f} s at load {la})")


if __name__ == "__main__":
    main()
