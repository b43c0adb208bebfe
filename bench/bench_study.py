"""``nmsid study`` at scale: 20 generated sessions, serial in-process vs 2 Dask workers.

Sessions come from ``testing/sessions.py`` (15 sE x 3 repeats at 2 kHz, the
paper's protocol; 20 seeds = 20 participants with their own parameter curves, noise and
mains levels). Two runs of the same study:

* identification of all 20 sessions, gap diagnosis off (it costs ~4 s per session); 10
  per worker: the median per-session cost and the speed-up need no more (40 sessions
  before: their generation alone took 86 s of the whole run);
* identification + gap diagnosis of the first ``GAP_SUBSET`` sessions.

Each is run serially in this process (``workers=0``) and on a LocalCluster of 2 worker
processes; wall times, their ratio, the median per-session cost and the peak memory
(RSS) of each worker are printed, then the estimate for 1,000 sessions on N machines
(docs/study.md explains it).

    python bench/bench_study.py
"""

from __future__ import annotations

import logging
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
for p in (ROOT, HERE):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from nmsid.study.config import StudyConfig  # noqa: E402
from nmsid.study.runner import run_study  # noqa: E402
from nmsid.testing.sessions import write_synthetic_session  # noqa: E402

N_SESSIONS = 20
GAP_SUBSET = 4
WORKERS = 2


def _run(cfg: StudyConfig, out: Path, workers: int):
    t0 = time.perf_counter()
    res = run_study(cfg, out, workers=workers, progress=None)
    return time.perf_counter() - t0, res.results, res.worker_peak_rss_MB, res.startup_s


def _compare(title: str, cfg: StudyConfig, tmp: Path) -> dict:
    load0 = os.getloadavg()[0]
    t_serial, r_serial, rss_serial, _ = _run(cfg, tmp / f"{title}-serial", 0)
    t_dask, r_dask, rss_dask, startup = _run(cfg, tmp / f"{title}-dask", WORKERS)
    per = statistics.median(r["elapsed_s"] for r in r_serial)
    per_dask = statistics.median(r["elapsed_s"] for r in r_dask)
    ok = sum(1 for r in r_dask if r["ok"])
    same = all(a["values"] == b["values"] for a, b in zip(r_serial, r_dask, strict=True) if a["ok"])
    print(f"{title}: {len(cfg.sessions)} sessions, {ok} identified; serial {t_serial:.1f} s, "
          f"{WORKERS} workers {t_dask:.1f} s, speed-up x{t_serial / t_dask:.2f}; median "
          f"per session {per:.2f} s serial, {per_dask:.2f} s in a worker; cluster start "
          f"{startup:.1f} s; results identical: {same}; load average {load0:.1f} -> "
          f"{os.getloadavg()[0]:.1f}")
    print(f"  peak RSS: serial process {max(rss_serial.values()):.0f} MB; workers "
          + ", ".join(f"{v:.0f} MB" for v in rss_dask.values()))
    return {"serial_s": t_serial, "dask_s": t_dask, "per_session_s": per,
            "per_session_worker_s": per_dask,
            "rss_MB": max(rss_dask.values()), "n": len(cfg.sessions)}


def estimate(ident: dict, gap: dict) -> None:
    """1,000 sessions on N machines of 8 cores (one single-threaded worker per core)."""
    t_id = ident["per_session_s"]
    t_gap = max(gap["per_session_s"] - t_id, 0.0)
    # per-task efficiency of a worker here: serial cost / cost in a worker (gap run: long
    # tasks, so cluster start and scheduling do not hide it); 1.0 on dedicated cores
    eff = min(1.0, gap["per_session_s"] / gap["per_session_worker_s"])
    cost = t_id + t_gap
    print(f"estimate, 1,000 sessions: per session {t_id:.2f} s identification + "
          f"{t_gap:.1f} s gap = {cost:.1f} s on one core (serial 1,000 x {cost:.1f} s = "
          f"{1000 * cost / 3600:.1f} h)")
    print(f"  8 cores/machine, one worker per core, {gap['rss_MB']:.0f} MB per worker; "
          f"per-task efficiency {eff:.2f} as measured here (2 shared cores) / 1.00 on "
          "dedicated cores; + a few s cluster start:")
    for machines in (1, 4, 16, 64):
        workers = 8 * machines
        lo = 1000 * cost / (workers * eff) / 60
        hi = 1000 * cost / workers / 60
        print(f"  {machines:>3} machine(s), {workers:>4} workers: {lo:6.1f} min here-like, "
              f"{hi:6.1f} min dedicated (memory {8 * gap['rss_MB'] / 1024:.1f} GB per "
              "machine; 1,000 x 28 MB = 28 GB read from the shared file system)")


def main() -> None:
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        t0 = time.perf_counter()
        paths = []
        for i in range(N_SESSIONS):
            p = tmp / "sessions" / f"SYN{100 + i:03d}.h5"
            write_synthetic_session(p, seed=100 + i)
            paths.append(p)
        size = sum(p.stat().st_size for p in paths) / 1e6
        print(f"generated {N_SESSIONS} sessions (15 sE x 3 repeats, 2 kHz, {N_SESSIONS} "
              "participants) "
              f"in {time.perf_counter() - t0:.0f} s, {size:.0f} MB on disk")
        ident = _compare("identification only", StudyConfig(
            sessions=paths, gap=False, figures=False, source="bench"), tmp)
        gap = _compare(f"identification + gap diagnosis, first {GAP_SUBSET}", StudyConfig(
            sessions=paths[:GAP_SUBSET], gap=True, figures=False, source="bench"), tmp)
        estimate(ident, gap)
        print("(2 shared cores: other processes on this machine inflate both times)")


if __name__ == "__main__":
    main()
