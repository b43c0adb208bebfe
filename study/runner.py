"""Run a study: one Dask task per session (paths in, small summaries out), then the group
analysis and the report.

``workers=0`` runs every session in this process, one after another (the baseline of
the bench); otherwise a ``distributed.LocalCluster`` with ``workers`` single-threaded
worker processes is started, or an existing scheduler is used (``scheduler=ADDRESS``:
every worker must see the session files and the output folder at the same paths).
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from nmsid.study.config import StudyConfig
from nmsid.study.group import GroupResult, write_group
from nmsid.study.report_html import draw_figures, write_report
from nmsid.study.tasks import peak_rss_MB, run_session, session_folder_name


@dataclass
class StudyOutputs:
    """What a study run produced."""

    results: list[dict]
    group: GroupResult
    report: Path
    elapsed_s: float
    mode: str
    worker_peak_rss_MB: dict[str, float]
    startup_s: float = 0.0
    """Time to start the local cluster and connect (0 when serial)."""


def _line(i: int, n: int, r: dict) -> str:
    name = Path(r["path"]).name
    if r.get("session_state") in ("live", "incomplete"):
        name += f" [{r['session_state'].upper()}: {r.get('state_note', '')}]"
    if not r.get("ok"):
        return f"[{i}/{n}] {name}: FAILED ({r['error']}) {r['elapsed_s']:.1f} s"
    gap = r.get("gap")
    extra = f", gap best effect {gap['best_effect']}" if gap else ""
    warn = f" [{r['error']}]" if r.get("error") else ""
    return (f"[{i}/{n}] {name}: {r['levels_identified']}/{r['levels']} levels{extra}, "
            f"{r['elapsed_s']:.1f} s{warn}")


def run_study(config: StudyConfig, out_dir: str | os.PathLike, *, workers: int | None = 2,
              scheduler: str | None = None,
              progress: Callable[[str], None] | None = print) -> StudyOutputs:
    """Identify and diagnose every session of ``config``, then write the group report.

    Parameters
    ----------
    config : StudyConfig
    out_dir : path-like
        Receives ``report.html``, the CSV/JSON tables and ``sessions/NNNN-name/``.
    workers : int, optional
        Worker processes of the local cluster; 0 = serial in this process.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); overrides ``workers``.
    progress : callable, optional
        Receives one line per finished session.
    """
    settings = config.identification_settings()
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    gap_set = config.gap_sessions()
    jobs = [(str(p), str(out / "sessions" / session_folder_name(p, i + 1)), p in gap_set)
            for i, p in enumerate(config.sessions)]
    say = progress or (lambda _text: None)
    t0 = time.perf_counter()
    results: list[dict] = []
    rss: dict[str, float] = {}
    if scheduler is None and not workers:
        mode = "serial, in-process"
        for i, (path, folder, gap) in enumerate(jobs):
            results.append(run_session(path, folder, settings, gap=gap))
            say(_line(i + 1, len(jobs), results[i]))
        rss["in-process"] = peak_rss_MB()
        startup = 0.0
    else:
        results, mode, rss, startup = _run_dask(jobs, settings, workers, scheduler, say)
    elapsed = time.perf_counter() - t0
    for r in results:  # the code used in the group tables ([participants] overrides)
        r["label"] = config.participants.get(Path(r["path"]).stem, r.get("participant", ""))
    group = write_group(results, out, settings, config.participants)
    if group.note:
        say(group.note)
    figures = draw_figures(group, out) if config.figures else []
    (out / "study.json").write_text(json.dumps({
        "format": "nmsid-study", "format_version": 1, "source": config.source,
        "mode": mode, "elapsed_s": elapsed, "worker_peak_rss_MB": rss,
        "sessions": [{k: v for k, v in r.items() if k != "traceback"} for r in results],
        "gap_summary": group.gap}, indent=1, default=str) + "\n", encoding="utf-8")
    report = write_report(out / "report.html", results, group, figures,
                          title=f"nmsid study: {Path(config.source).name}",
                          elapsed_s=elapsed, mode=mode)
    return StudyOutputs(results, group, report, elapsed, mode, rss, startup)


def _run_dask(jobs, settings, workers, scheduler, say):
    # dask/distributed are optional (extra "study") and slow to import
    import dask
    from distributed import Client, LocalCluster, as_completed
    # The worker's statistical profiler samples every thread's stack every 10 ms under
    # the GIL; on small CPU-bound tasks it cost as much as the task (bench_study).
    dask.config.set({"distributed.worker.profile.enabled": False})
    # distributed makes workers return freed memory to the OS at 64 KiB
    # (MALLOC_TRIM_THRESHOLD_); the analysis allocates and frees MB-sized arrays all the
    # time, and with that setting a gap diagnosis took 1.7x the CPU of the same run
    # outside Dask. Keep one BLAS/OpenMP thread per worker, glibc's own trimming.
    dask.config.set({"distributed.nanny.pre-spawn-environ": {
        "OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}})
    # distributed logs every connection at INFO; show it only when asked (nmsid -v)
    if logging.getLogger().getEffectiveLevel() > logging.INFO:
        logging.getLogger("distributed").setLevel(logging.ERROR)
    t0 = time.perf_counter()
    cluster = None
    if scheduler is not None:
        client = Client(scheduler)
        mode = f"Dask scheduler {scheduler}"
    else:
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.CRITICAL)
        client = Client(cluster)
        mode = f"Dask LocalCluster, {int(workers)} worker process(es)"
    startup = time.perf_counter() - t0
    try:
        futures = {client.submit(run_session, path, folder, settings, gap=gap, pure=False,
                                 key=f"session-{i:05d}"): i
                   for i, (path, folder, gap) in enumerate(jobs)}
        results: list[dict | None] = [None] * len(jobs)
        done = 0
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                res: dict = fut.result()
            except Exception as exc:  # the worker died (memory, kill): report, go on
                res = {"path": jobs[i][0], "ok": False, "participant": "",
                       "error": f"task failed: {type(exc).__name__}: {exc}",
                       "elapsed_s": 0.0, "peak_rss_MB": float("nan"),
                       "gap": None, "problems": []}
            results[i] = res
            done += 1
            say(_line(done, len(jobs), res))
        rss = {str(addr): float(v) / 1024.0 for addr, v in
               client.run(lambda: __import__("resource").getrusage(
                   __import__("resource").RUSAGE_SELF).ru_maxrss).items()}
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return results, mode, rss, startup
