"""The floor of ``bench_identify_process``: the least any identification of the session
must do, run as its own process.

    python bench/identify_floor_process.py SESSION.h5

Start Python; import numpy, h5py and ``scipy.signal``; read ``rE`` and ``force_N`` of every trial
with h5py's low-level call into preallocated arrays (no attribute, no contract check); one
zero-phase 4th-order low-pass of every trial at once (``scipy.signal.lfilter``,
forward and backward), decimation by 10; one *linear* least-squares fit per trial (a
second-order ARX model: no nonlinear search, no confidence intervals). Nothing is
validated, no trial is judged, nothing is written.

What ``nmsid identify`` does on top of this, the floor does not: the contract's checks of
the file, trial QC (spikes, stalls, clipping, noise, repeats against each other), 75
nonlinear fits with their uncertainties, AICc model selection, the twin and seven output
files. The time between the floor and the 0.3 s target is what all of that may cost.
"""

from __future__ import annotations

import sys
import time

T0 = time.perf_counter()

import h5py  # noqa: E402
import numpy as np  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

#: 4th-order Butterworth low-pass at 20 Hz for 2000 Hz as two biquads (scipy.signal.butter(
#: 4, 20, fs=2000, output="sos"), written out: the floor designs no filter)
SOS = np.array([[8.984861463970648e-07, 1.7969722927941296e-06, 8.984861463970648e-07,
                 1.0, -1.8866095826215064, 0.8903397362840242],
                [1.0, 2.0, 1.0, 1.0, -1.9492159580258417, 0.9530698953278909]])


def read(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(rE, force_N) of every trial as rows (trials of one length, as in the bench)."""
    rows: dict[str, list[np.ndarray]] = {"rE": [], "force_N": []}
    with h5py.File(path, "r") as f:
        trials = f["trials"]
        for name in trials:
            for key, out in rows.items():
                ds = trials[name][key]
                a = np.empty(ds.shape)
                ds.id.read(h5py.h5s.ALL, h5py.h5s.ALL, a)
                out.append(a)
    return np.vstack(rows["rE"]), np.vstack(rows["force_N"])


def zero_phase(x: np.ndarray) -> np.ndarray:
    """Each row through SOS forward, then backward."""
    for direction in (1, -1):
        x = x[:, ::direction]
        for s in SOS:
            x = lfilter(s[:3], s[3:], x, axis=1)
        x = x[:, ::direction]
    return x


def main(argv: list[str]) -> int:
    u, y = read(argv[1])
    y = zero_phase(y)[:, ::10]
    u = u[:, ::10]
    for k in range(y.shape[0]):
        X = np.column_stack([y[k, 1:-1], y[k, :-2], u[k, 1:-1], u[k, :-2],
                             np.ones(y.shape[1] - 2)])
        np.linalg.lstsq(X, y[k, 2:], rcond=None)
    print(f"floor: {y.shape[0]} trials read, filtered and fitted in "
          f"{time.perf_counter() - T0:.3f} s after the interpreter started")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
