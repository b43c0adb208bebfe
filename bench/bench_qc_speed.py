"""Trial QC's speed (issue 30, speed item): ``assess_session`` in process on the 45-trial
simulated session of ``bench_identify_process``, against the same QC with the
computations this branch replaced, in the same process on the same read session.

    python bench/bench_qc_speed.py                 # 7 runs of each
    python bench/bench_qc_speed.py --runs 3
    python bench/bench_qc_speed.py --session FILE  # an existing session instead

The session is recorded by the simulator (``nmsid run --backend sim --participant B
--seed 12``: 15 sE x 3 repeats, 2000 Hz, 15 s trials). Figures are median CPU times
(``time.process_time``: user + sys of this process; a loaded machine stretches them less
than wall time) of ``--runs`` calls after one warm-up call, with ``OPENBLAS_NUM_THREADS=1``
as ``nmsid identify`` runs.

The baseline is the same QC with its former computations put back for the steps that
were replaced (like for like; the steps that only stopped repeating work stay):

* ``np.median`` and ``np.quantile`` instead of the one-partition medians and quantile;
* every regression building its own normal matrix to start from.

The stages are timed in the fast run: the two zero-phase filters over all trials, the
per-trial checks, the comparison of the repeats (most of it the IRLS normal matrices),
the fatigue estimate. Target: ``assess_session`` <= 0.08 s in process (from 0.21-0.27 s).
"""

from __future__ import annotations

import collections
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (ROOT, HERE):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

import numpy as np  # noqa: E402
from cpu_time import cpu_median, load_1min  # noqa: E402
from workers import child_env  # noqa: E402

from nmsid.analysis.qc import checks, decide, repeats  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402

TARGET_S = 0.08


def _arg(name: str, default: str) -> str:
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default




@contextlib.contextmanager
def _former_computations():
    """The replaced computations back in place (see the module's docstring)."""
    saved = (checks.median_of_finite, checks.quantile_of_finite, repeats._Reference.start)

    def start(self, inside):
        X = self.regressors[inside]
        Xw = X * np.ones(X.shape[0])[:, None]
        return X, Xw, Xw.T @ X

    checks.median_of_finite = lambda x, scratch=False: float(np.median(x))
    checks.quantile_of_finite = lambda x, q, scratch=False: float(np.quantile(x, q))
    repeats._Reference.start = start
    try:
        yield
    finally:
        (checks.median_of_finite, checks.quantile_of_finite,
         repeats._Reference.start) = saved


def _stages(session, runs: int) -> dict[str, float]:
    """Median CPU seconds of each stage inside assess_session."""
    names = {"_filter_together": "the two zero-phase filters, all trials",
             "_single": "per-trial checks (45)",
             "_compare": "the repeats compared (15 levels)",
             "_weighted_solve": "  of which the IRLS weighted solves",
             "_session_fatigue": "fatigue from the kept repeats"}
    owner = {n: repeats if n == "_weighted_solve" else decide for n in names}
    acc: dict[str, float] = collections.defaultdict(float)
    saved = {n: getattr(owner[n], n) for n in names}

    def timed(name, fn):
        def run(*a, **k):
            t0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                acc[name] += time.process_time() - t0
        return run

    for n, fn in saved.items():
        setattr(owner[n], n, timed(n, fn))
    per: dict[str, list[float]] = collections.defaultdict(list)
    try:
        decide.assess_session(session)
        for _ in range(runs):
            acc.clear()
            decide.assess_session(session)
            for n in names:
                per[n].append(acc[n])
    finally:
        for n, fn in saved.items():
            setattr(owner[n], n, fn)
    return {names[n]: statistics.median(v) for n, v in per.items()}


def _verdicts(qc) -> list:
    return [(v.trial, v.decision, tuple(v.spans), v.level_flag) for v in qc.trials]


def main() -> None:
    runs = int(_arg("--runs", "7"))
    given = _arg("--session", "")
    with tempfile.TemporaryDirectory() as d:
        if given:
            path = Path(given)
        else:
            subprocess.run([sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim",
                            "--participant", "B", "--outdir", d, "--seed", "12"],
                           check=True, env=child_env(), cwd=ROOT, stdout=subprocess.DEVNULL)
            path = next(Path(d).glob("B-*.h5"))
        session = read_session(path, datasets=("rE", "force_N"))
    n = sum(t.completed for t in session.trials)
    ours = cpu_median(lambda: decide.assess_session(session), runs)
    with _former_computations():
        former = cpu_median(lambda: decide.assess_session(session), runs)
        former_verdicts = _verdicts(decide.assess_session(session))
    same = _verdicts(decide.assess_session(session)) == former_verdicts
    stages = _stages(session, runs)
    print(f"assess_session, {n} trials ({path.name if given else 'simulated, B seed 12'}), "
          f"median CPU of {runs} calls, OPENBLAS_NUM_THREADS="
          f"{os.environ.get('OPENBLAS_NUM_THREADS')}, load {load_1min()}:")
    verdict = "met" if ours <= TARGET_S else "missed"
    print(f"  QC in process {ours * 1e3:7.1f} ms CPU   the former computations "
          f"{former * 1e3:7.1f} ms: x{former / ours:.2f}; target <= {TARGET_S * 1e3:.0f} ms: "
          f"{verdict}")
    print(f"  decisions, spans and level flags the same as with the former computations: "
          f"{'yes' if same else 'NO'}")
    print("  where the time goes (fast run, median CPU per stage):")
    for name, s in stages.items():
        print(f"    {name:42s} {s * 1e3:7.1f} ms")


if __name__ == "__main__":
    main()
