"""The session store: the cost of a trial end and the peak disk use of a 45-trial session.

The design (``rig.session_log`` / ``protocols.session_publish``): each trial end writes the
trial's journal entry (encoded like the file: A/D counts, shuffle + deflate) and appends it
to the in-memory file; the file is published (temp + fsync + atomic replace) when it is
created with the calibration and once at the end. The baseline, run in the same process on
the same trials, is the design before (issue 24): a float64 ``.npz`` journal entry, then a
whole new version of the file published at every trial end.

Figures: the time of the first and of the last trial end (target: no growth with the
trial number), the one publish at the end, and the peak bytes in the session's folder
(target: at most 2x the final file), measured at every trial end and just before every
rename of a new version (the moment the temp file and the old version both exist).
A paper session: 45 trials of 15 s at 2 kHz with a 16-bit 6-axis wrench and a sync line.

    python bench/bench_store.py            # the paper session
    python bench/bench_store.py --small    # 10 trials of 2 s (a quick check)
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import nmsid.protocols.session_publish as pub
from nmsid.protocols.session_file import Calibration, SessionWriter, Trial
from nmsid.rig.journal import trial_meta, write_durable
from nmsid.rig.session_log import SessionLog

N_TRIALS = 45
N_SAMPLES = 30_000  # 15 s at 2 kHz


def _trial(i: int, rng, n: int) -> Trial:
    t = np.arange(n) / 2000.0
    lsb = 20.0 / 65536
    return Trial(sE=0.3 + 0.05 * (i % 15), repeat=1 + i // 15, fs_Hz=2000.0,
                 rE=0.5 + 0.5 * np.sin(t), I_ext_mA=4 + 3 * np.sin(t),
                 I_flex_mA=4 - 3 * np.sin(t), force_N=rng.normal(size=n),
                 wrench=np.rint(rng.normal(scale=300, size=(n, 6))) * lsb,
                 sync=(np.sin(40 * t) > 0) * 5.0, started_utc="2026-11-22T01:00:00Z",
                 extra_attrs={"schedule_index": i})


class DiskWatch:
    """The largest total size of the files under a folder, sampled at chosen moments
    and just before each publish renames its temp file."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.peak = 0

    def sample(self) -> None:
        total = 0
        for dirpath, _, files in os.walk(self.folder):
            for name in files:
                try:
                    total += os.stat(os.path.join(dirpath, name)).st_size
                except FileNotFoundError:
                    pass
        self.peak = max(self.peak, total)

    def __enter__(self) -> DiskWatch:  # noqa: PYI034
        self._replace, self._new = pub.replace_retrying, pub._publish_new

        def replace(src, dst, **kw):
            self.sample()
            return self._replace(src, dst, **kw)

        def new(tmp, path, delays_s):
            self.sample()
            return self._new(tmp, path, delays_s)
        pub.replace_retrying, pub._publish_new = replace, new
        return self

    def __exit__(self, *exc) -> None:
        pub.replace_retrying, pub._publish_new = self._replace, self._new


def _old_entry(target: Path, trial: Trial) -> None:
    """The journal entry as the design before wrote it: float64 arrays, stored plainly."""
    arrays = {k: np.asarray(getattr(trial, k), dtype=np.float64)
              for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync")}
    meta = np.array(json.dumps(trial_meta(trial)))
    write_durable(target, lambda fh: np.savez(fh, __meta__=meta, **arrays))


def _timed(fn) -> tuple[float, float]:
    """(wall s, CPU s of this process) of ``fn()``."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def _new_design(folder: Path, trials: list[Trial]) -> dict:
    path = folder / "new.h5"
    with DiskWatch(folder) as disk:
        log = SessionLog.create(path, participant="B01", config_json="{}", seed=1,
                                backend="bench", schedule_json="[]")
        log.write_calibration(Calibration(2.0, 9.5, 1.5, 8.0))
        wall, cpu = [], []
        for t in trials:
            w, c = _timed(lambda t=t: log.end_trial(t))
            wall.append(w)
            cpu.append(c)
            disk.sample()
        journal = sum(p.stat().st_size for p in log.jdir.iterdir())
        end_s, _ = _timed(lambda: log.finish())
        assert not log.jdir.exists()
    return {"wall": wall, "cpu": cpu, "end_s": end_s, "peak": disk.peak,
            "journal": journal, "final": path.stat().st_size}


def _old_design(folder: Path, trials: list[Trial]) -> dict:
    path = folder / "old.h5"
    jdir = folder / "old.h5.journal"
    jdir.mkdir()
    with DiskWatch(folder) as disk:
        w = SessionWriter.create(path, participant="B01")
        w.write_calibration(Calibration(2.0, 9.5, 1.5, 8.0))
        wall, cpu = [], []
        for i, t in enumerate(trials):
            def end(i=i, t=t):
                _old_entry(jdir / f"trial-{i + 1:04d}.npz", t)
                w.append_trial(t)  # publishes a whole new version of the file
            a, c = _timed(end)
            wall.append(a)
            cpu.append(c)
            disk.sample()
    return {"wall": wall, "cpu": cpu, "peak": disk.peak, "final": path.stat().st_size}


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    n_trials, n = (10, 4000) if "--small" in argv else (N_TRIALS, N_SAMPLES)
    rng = np.random.default_rng(1)
    trials = [_trial(i, rng, n) for i in range(n_trials)]
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as tmp:
        a, b = Path(tmp) / "new", Path(tmp) / "old"
        a.mkdir()
        b.mkdir()
        new = _new_design(a, trials)
        old = _old_design(b, trials)
    print(f"bench_store: {n_trials} trials of {n} samples (+ wrench, sync); final file "
          f"{new['final'] / 1e6:.1f} MB (the design before: {old['final'] / 1e6:.1f} MB); "
          "the two designs run one after the other in this process")
    for clock in ("wall", "cpu"):
        x, y = new[clock], old[clock]
        for name, pick in (("first", lambda v: v[0]), ("median", statistics.median),
                           ("last", lambda v: v[-1])):
            print(f"  trial end, {clock:4s} {name:6s}: {1000 * pick(x):7.1f} ms   design "
                  f"before {1000 * pick(y):7.1f} ms   ratio {pick(x) / pick(y):5.2f}x")
    k = max(1, n_trials // 5)

    def growth(v):
        return statistics.median(v[-k:]) / statistics.median(v[:k])
    g_cpu, g_wall = growth(new["cpu"]), growth(new["wall"])
    print(f"  growth, median of the last {k} / first {k} trial ends: CPU {g_cpu:.2f}x "
          f"(design before {growth(old['cpu']):.2f}x), wall {g_wall:.2f}x (design before "
          f"{growth(old['wall']):.2f}x); target <= 1.2x on CPU time (the work; the wall "
          f"time of a shared machine swings with its load): "
          f"{'met' if g_cpu <= 1.2 else 'missed'}")
    print(f"  session end (the one publish of the whole file, and its check): "
          f"{1000 * new['end_s']:.0f} ms; all trial ends {sum(new['wall']):.1f} s wall vs "
          f"design before {sum(old['wall']):.1f} s (ratio "
          f"{sum(new['wall']) / sum(old['wall']):.2f}x)")
    print(f"  journal {new['journal'] / 1e6:.1f} MB = {new['journal'] / new['final']:.2f}x "
          "the file")
    ratio, ratio_old = new["peak"] / new["final"], old["peak"] / old["final"]
    print(f"  peak disk {new['peak'] / 1e6:.1f} MB = {ratio:.2f}x the final file; design "
          f"before {old['peak'] / 1e6:.1f} MB = {ratio_old:.2f}x; target <= 2x: "
          f"{'met' if ratio <= 2.0 else 'missed'}")

if __name__ == "__main__":
    main()
