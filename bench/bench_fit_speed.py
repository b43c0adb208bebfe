"""The identification's fits at the speed of their data: CPU time of the level fits, the
repeats' own fits (scatter, fatigue) and their preprocessing, in one process.

    python bench/bench_fit_speed.py              # 7 timed runs of each part
    python bench/bench_fit_speed.py --runs 3     # fewer

The session is the one ``bench_identify_process`` times as a whole process: recorded by
the simulator (``nmsid run --backend sim``, participant B, seed 12: 15 sE x 3 repeats,
2000 Hz, 15 s trials; its zero-order hold makes the input timing significant, so each
level is fitted twice), read once. Timed, as CPU time of this process
(``time.process_time``, median of the runs after one warm-up; wall time on a shared
machine is stretched by the others' load), with QC off (QC is timed by ``bench_qc``):

* ``identify_session(..., trial_scatter=False)``: the 15 levels (preprocessing, fit
  without a delay, the delay estimate, refit with it);
* ``identify_session(..., trial_scatter=True)``: the same plus each repeat fitted on its
  own (45 fits) and the fatigue;
* the preprocessing alone: the same ``preprocess_trials`` calls through one
  ``TrialSignals`` cache (the filters run once per repeat and input delay).

Baseline (fairest, same process, like for like): the plain discretised fit of
``bench/plain_identify_process.py`` (``least_squares`` over the ZOH model run by
``lfilter``, 3 starts) on exactly the 200 Hz data of each level ours fits: CPU time per
fit against ours per fit (75 fits: 30 level fits, 45 repeat fits). Target (issue 30,
speed item of the fits): levels + repeats + preprocessing <= 60 ms.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

# one BLAS thread, as nmsid identify starts itself (nmsid.cli.limit_blas_threads): its
# small solves are slower, and cost twice the CPU, with OpenBLAS's thread per core
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
for _p in (HERE.parent, HERE):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from cpu_time import cpu_median, load_1min  # noqa: E402

from nmsid.analysis.identify import identify_session  # noqa: E402
from nmsid.analysis.preprocess import TrialSignals, preprocess_trials  # noqa: E402
from nmsid.analysis.settings import IdentificationSettings  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402

#: Levels + repeats + preprocessing, in process, CPU seconds (issue 30's fit item).
TARGET_S = 0.060


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args(argv)
    from bench_identify_process import make_session
    from plain_identify_process import plain_fit

    with tempfile.TemporaryDirectory() as d:
        session = read_session(make_session(Path(d)), datasets=("rE", "force_N"))
    s = IdentificationSettings(qc=False)
    load0 = load_1min()
    result = identify_session(session, s)
    groups: dict[float, list] = {}
    for tr in session.trials:
        groups.setdefault(round(float(tr.sE), 9), []).append(tr)
    delays = {round(lv.sE, 9): lv.data.input_delay_s for lv in result.levels if lv.data}
    n_level_fits = 15 + sum(1 for v in delays.values() if v != 0.0)
    n_trial_fits = len(result.scatter.trials) if result.scatter else 0

    def levels():
        identify_session(session, s, trial_scatter=False)

    def whole():
        identify_session(session, s, trial_scatter=True)

    def preprocessing():
        cache = TrialSignals(s)
        for key, trials in groups.items():
            preprocess_trials(trials, s, input_delay_s=0.0, cache=cache)
            if delays.get(key, 0.0) != 0.0:
                preprocess_trials(trials, s, input_delay_s=delays[key], cache=cache)
            for tr in trials:
                preprocess_trials([tr], s, input_delay_s=delays.get(key, 0.0), cache=cache)

    prepared = [preprocess_trials(groups[k], s, input_delay_s=delays.get(k, 0.0))
                for k in sorted(groups)]

    def plain():
        for dd in prepared:
            plain_fit(dd.u, dd.y_N, dd.fs_Hz)

    t_levels = cpu_median(levels, args.runs)
    t_whole = cpu_median(whole, args.runs)
    t_pre = cpu_median(preprocessing, args.runs)
    t_plain = cpu_median(plain, max(1, args.runs // 3))
    load1 = load_1min()
    fits = t_whole - t_pre
    n_fits = n_level_fits + n_trial_fits
    ours_per_fit = fits / n_fits
    plain_per_fit = t_plain / len(prepared)
    print(f"45-trial simulated session (15 sE x 3 repeats, 2000 Hz, 15 s), QC off; CPU "
          f"time of this process, median of {args.runs} runs; load average {load0} -> "
          f"{load1}")
    print(f"  levels (preprocessing + {n_level_fits} level fits + delay estimates): "
          f"{t_levels * 1e3:.1f} ms")
    print(f"  levels + {n_trial_fits} repeat fits + fatigue: {t_whole * 1e3:.1f} ms   "
          f"target <= {TARGET_S * 1e3:.0f} ms: "
          f"{'met' if t_whole <= TARGET_S else 'missed'} (x{t_whole / TARGET_S:.2f} of it)")
    print(f"    of which preprocessing (filters of 45 repeats and the rE records, one "
          f"cache): {t_pre * 1e3:.1f} ms ({100 * t_pre / t_whole:.0f} %); fits and the "
          f"rest: {fits * 1e3:.1f} ms")
    print(f"  per fit: ours {ours_per_fit * 1e3:.2f} ms ({n_fits} fits, everything but the "
          f"preprocessing) vs the plain discretised fit {plain_per_fit * 1e3:.1f} ms on the "
          f"same 200 Hz data (baseline, fairest: bench/plain_identify_process.py): "
          f"x{plain_per_fit / ours_per_fit:.1f}")


if __name__ == "__main__":
    main(sys.argv[1:])
