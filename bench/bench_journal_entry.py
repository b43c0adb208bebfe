"""The journal entry of one trial (``rig.journal.save_trial_npz``): CPU time and size.

The entry is numpy's own ``np.savez_compressed`` of the members the session file's
encoding gives (A/D counts, byte-shuffled arrays). The baseline, run in the same process
on the same trial, is ``np.savez`` of the same members (stored, not deflated): faster, but
about twice the bytes, which ``bench_store.py``'s peak-disk target (at most 2x the final
file) does not allow. A 15 s trial at 2 kHz with a wrench and a sync line, from a
simulated session (``nmsid.run_simulated_session``).

    python bench/bench_journal_entry.py
"""

from __future__ import annotations

import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import nmsid  # noqa: E402
from nmsid.rig import journal  # noqa: E402

REPEATS = 9


def _trial():
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "one.toml"
        config.write_text('participant = "B01"\n[protocol]\nsE_levels = [0.6]\nrepeats = 1\n')
        run = nmsid.run_simulated_session(Path(tmp) / "one.h5", config, seed=1)
        return nmsid.read_session(run.path).trials[0]


def _best_cpu(write) -> tuple[float, int]:
    """(best CPU seconds, bytes) of ``write(fileobj)`` over REPEATS runs, in memory."""
    best, size = float("inf"), 0
    for _ in range(REPEATS):
        buf = io.BytesIO()
        t0 = time.process_time()
        write(buf)
        best = min(best, time.process_time() - t0)
        size = buf.tell()
    return best, size


def main() -> None:
    trial = _trial()
    ours, ours_bytes = _best_cpu(
        lambda fh: np.savez_compressed(fh, **journal.trial_members(trial)))
    base, base_bytes = _best_cpu(lambda fh: np.savez(fh, **journal.trial_members(trial)))
    raw = sum(getattr(trial, k).nbytes for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N",
                                                   "wrench", "sync"))
    print(f"bench_journal_entry: one trial of {trial.n_samples} samples + wrench + sync "
          f"({raw / 1e6:.2f} MB as float64), encoding included, best of {REPEATS}")
    print(f"  np.savez_compressed (the entry): {1000 * ours:6.1f} ms CPU, "
          f"{ours_bytes / 1e6:.2f} MB")
    print(f"  np.savez (stored, baseline)    : {1000 * base:6.1f} ms CPU, "
          f"{base_bytes / 1e6:.2f} MB; ratio CPU {ours / base:.2f}x, bytes "
          f"{ours_bytes / base_bytes:.2f}x")


if __name__ == "__main__":
    main()
