"""What publishing each new version of the session file costs, per trial.

The writer changes an in-memory image of the file and publishes each version by temp
file + fsync + atomic rename (``protocols.session_publish``), so readers never disturb it
and a full disk never touches the published file. The baseline, run in the same process on
the same data with the same encoding (``SessionWriter._add_trial``: shuffle + deflate,
Fletcher-32, A/D counts), is what the writer did before: open the file in place with h5py
(``"a"``), append the trial, close. A paper session: 45 trials of 15 s at 2 kHz with a
16-bit 6-axis wrench and a sync line.

    python bench/bench_store.py
"""

from __future__ import annotations

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

import h5py  # noqa: E402

from nmsid.protocols.session_file import Calibration, SessionWriter, Trial  # noqa: E402

N_TRIALS = 45
N_SAMPLES = 30_000  # 15 s at 2 kHz


def _trial(i: int, rng) -> Trial:
    t = np.arange(N_SAMPLES) / 2000.0
    lsb = 20.0 / 65536
    return Trial(sE=0.3 + 0.05 * (i % 15), repeat=1 + i // 15, fs_Hz=2000.0,
                 rE=0.5 + 0.5 * np.sin(t), I_ext_mA=4 + 3 * np.sin(t),
                 I_flex_mA=4 - 3 * np.sin(t), force_N=rng.normal(size=N_SAMPLES),
                 wrench=np.rint(rng.normal(scale=300, size=(N_SAMPLES, 6))) * lsb,
                 sync=(np.sin(40 * t) > 0) * 5.0, started_utc="2026-11-22T01:00:00Z")


def _run(folder: Path, trials, in_place: bool) -> list[float]:
    path = folder / ("inplace.h5" if in_place else "publish.h5")
    w = SessionWriter.create(path, participant="B01")
    w.write_calibration(Calibration(2.0, 9.5, 1.5, 8.0))
    times = []
    for t in trials:
        t0 = time.perf_counter()
        if in_place:
            with h5py.File(path, "a") as f:
                w._add_trial(f, t)
            fd = os.open(path, os.O_RDONLY)  # the same durability: fsync the file
            os.fsync(fd)
            os.close(fd)
        else:
            w.append_trial(t)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    rng = np.random.default_rng(1)
    trials = [_trial(i, rng) for i in range(N_TRIALS)]
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as tmp:
        folder = Path(tmp)
        base = _run(folder, trials, in_place=True)
        new = _run(folder, trials, in_place=False)
        size_MB = (folder / "publish.h5").stat().st_size / 1e6
    print(f"bench_store: {N_TRIALS} trials of {N_SAMPLES} samples (+ wrench, sync); final "
          f"file {size_MB:.1f} MB")
    for name, fn in (("median", statistics.median), ("last (largest file)", lambda x: x[-1]),
                     ("total", sum)):
        b, n = fn(base), fn(new)
        print(f"  per-trial write, {name:20s}: publish {1000 * n:8.1f} ms   in place "
              f"{1000 * b:8.1f} ms   ratio {n / b:5.2f}x")
    print(f"  share of a 15 s trial + 60 s rest spent publishing (last trial): "
          f"{100 * new[-1] / 75:.2f} %")


if __name__ == "__main__":
    main()
