"""Compact session files and NWB export: sizes, times, nwbinspector findings.

1. The demo session (simulated rig, 45 trials, calibration, wrench, sync) is rewritten
   through ``SessionWriter`` uncompressed (the old files) and with shuffle + gzip levels
   1-9: file size, write time (one open/close per trial, as the rig writes) and the time
   to read all force data (``read_session(datasets=("force_N",))``, best of 3) and all
   datasets; ratios against the uncompressed file, in this process.
2. The same session exported to NWB: time, size, nwbinspector's findings.

    python bench/bench_share.py
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from protocols.config import config_from_dict  # noqa: E402
from protocols.session_file import (SessionWriter, read_session,  # noqa: E402
                                    validate_session)
from rig.engine import Engine, TripPolicy  # noqa: E402
from sim_backends import make_sim_rig  # noqa: E402


def demo_session(tmp: Path) -> Path:
    """A whole simulated session as ``nmsid run --backend sim`` writes it."""
    rig = make_sim_rig(seed=0)
    cfg = config_from_dict({"participant": "DEMO", "seed": 0, "protocol": {"rest_s": 0.0}})
    path = tmp / "DEMO.h5"
    Engine(cfg, rig, path, trip_policy=TripPolicy.END_SESSION).run()
    return path


def rewrite(session, path: Path, level) -> float:
    t0 = time.perf_counter()
    w = SessionWriter.create(path, participant=session.participant,
                             created_utc=session.created_utc, config_json=session.config_json,
                             seed=session.seed, backend=session.backend, gzip_level=level)
    w.write_calibration(session.calibration)
    for t in session.trials:
        w.append_trial(t)
    w.append_events(session.events)
    return time.perf_counter() - t0


def best_of(fn, n: int = 3) -> float:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return min(out)


def files(tmp: Path) -> Path:
    src = demo_session(tmp)
    session = read_session(src)
    n = sum(t.n_samples for t in session.trials)
    print(f"demo session: {len(session.trials)} trials, {n} samples, as the rig wrote it "
          f"{src.stat().st_size / 1e6:.1f} MB (gzip level 4)")
    print(f"{'datasets':<14}{'size MB':>9}{'vs old':>8}{'write s':>9}{'read force s':>14}"
          f"{'vs old':>8}{'read all s':>12}{'vs old':>8}  valid")
    base = None
    for level in (None, 1, 2, 3, 4, 5, 6, 7, 8, 9):
        path = tmp / f"L{level}.h5"
        t_write = rewrite(session, path, level)
        size = path.stat().st_size / 1e6
        t_force = best_of(lambda: read_session(path, datasets=("force_N",)))
        t_all = best_of(lambda: read_session(path))
        if base is None:
            base = (size, t_force, t_all)
        back = read_session(path)
        exact = all(np.array_equal(a.force_N, b.force_N) and np.array_equal(a.wrench, b.wrench)
                    and np.array_equal(a.rE, b.rE) for a, b in zip(session.trials, back.trials))
        label = "old (plain)" if level is None else f"gzip {level}"
        print(f"{label:<14}{size:9.1f}{size / base[0]:8.2f}{t_write:9.2f}{t_force:14.3f}"
              f"{t_force / base[1]:8.2f}{t_all:12.3f}{t_all / base[2]:8.2f}  "
              f"{validate_session(path) == []}{'' if exact else '  NOT BIT-EXACT'}")
        if level not in (None, 4):
            path.unlink()
    w = np.concatenate([t.wrench for t in session.trials])
    w32 = w.astype(np.float32).astype(np.float64)
    stored = [t.wrench.dtype for t in read_session(tmp / "L4.h5").trials]
    print(f"wrench stored as {stored[0]} (float32 only when bit-exact); as float32 it would "
          f"change {np.mean(w32 != w) * 100:.0f} % of its samples by up to "
          f"{np.max(np.abs(w32 - w)):.2g} N or N*m: not lossless, so not done")
    return tmp / "L4.h5"


def nwb(src: Path, tmp: Path) -> None:
    try:
        from export.nwb import export_nwb, inspect_nwb
        import pynwb  # noqa: F401
    except ImportError as exc:
        print(f"NWB export skipped: {exc}")
        return
    t0 = time.perf_counter()
    out = export_nwb(src, tmp / "DEMO.nwb")
    t_export = time.perf_counter() - t0
    t0 = time.perf_counter()
    findings = inspect_nwb(out.path)
    t_inspect = time.perf_counter() - t0
    print(f"NWB export: {out.n_trials} trials, {out.n_series} time series, {out.n_events} "
          f"events, {out.path.stat().st_size / 1e6:.1f} MB in {t_export:.1f} s; "
          f"nwbinspector {t_inspect:.1f} s, {len(findings)} finding(s):")
    for m in findings:
        print(f"  {m.importance.name}: {m.check_function_name}: {m.message}")
    crit = [m for m in findings if m.importance.name in ("CRITICAL", "PYNWB_VALIDATION",
                                                          "ERROR")]
    print(f"  critical: {len(crit)} (experimenter / institution are not known to nmsid: "
          "give --experimenter / --institution)")


def main() -> None:
    logging.disable(logging.WARNING)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        src = files(tmp)
        nwb(src, tmp)


if __name__ == "__main__":
    main()
