"""Session-file fuzz: how many damaged or hostile files were tried, and the worst time and
memory any of them cost ``validate_session`` + ``read_session``.

Mutations of a small valid file (2 trials of 1000 samples): attributes set to strings,
NaN, inf, huge or negative values, arrays and escapes; samples set to NaN / inf / 1e300;
items deleted; external and soft links; truncation at any length; single bit flips
anywhere. Baseline: the same two calls on the unmutated file, in the same process. Memory
is the peak of Python + numpy allocations (``tracemalloc``) per file.

    python bench/bench_fuzz_sessions.py
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import h5py  # noqa: E402

from nmsid.protocols.session_file import (  # noqa: E402
    Calibration,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    validate_session,
)

N_FILES = 300
ATTRS = [("/", "format_version"), ("/", "participant"), ("/", "seed"),
         ("calibration", "Iemin_mA"), ("calibration", "Iemax_mA"), ("calibration", "Fmax_N"),
         ("trials/t001", "sE"), ("trials/t001", "fs_Hz"), ("trials/t002", "repeat"),
         ("trials/t002", "chirp_s"), ("trials/t001", "status"), ("trials/t002", "steady_s")]
VALUES = ["x", "", "2000", np.nan, np.inf, -np.inf, 1e300, -1.0, 0.0, 1.5, 2 ** 62,
          np.array([1.0, 2.0]), "\x1b[2J", True, np.zeros(4000)]
DATASETS = ["trials/t001/force_N", "trials/t002/rE", "trials/t001/I_flex_mA",
            "trials/t002/I_ext_mA"]


def _good(path: Path) -> Path:
    w = SessionWriter.create(path, participant="F01")
    w.write_calibration(Calibration(2.0, 9.5, 1.5, 8.0))
    rng = np.random.default_rng(1)
    for i in range(2):
        n = 1000
        w.append_trial(Trial(sE=0.5, repeat=i + 1, fs_Hz=2000.0, steady_s=0.25, chirp_s=0.25,
                             rE=np.full(n, 0.5), I_ext_mA=np.full(n, 3.0),
                             I_flex_mA=np.full(n, 2.0), force_N=rng.normal(size=n)))
    return path


def _mutate(path: Path, rng) -> str:
    kind = rng.choice(["attr", "data", "drop", "link", "truncate", "flip"],
                      p=[0.3, 0.15, 0.1, 0.05, 0.15, 0.25])
    if kind in ("truncate", "flip"):
        raw = bytearray(path.read_bytes())
        at = int(rng.integers(0, len(raw)))
        if kind == "truncate":
            raw = raw[:at]
        else:
            raw[at] ^= 1 << int(rng.integers(0, 8))
        path.write_bytes(bytes(raw))
        return kind
    with h5py.File(path, "a") as f:
        if kind == "attr":
            item, key = ATTRS[rng.integers(len(ATTRS))]
            f[item].attrs[key] = VALUES[rng.integers(len(VALUES))]
        elif kind == "data":
            name = DATASETS[rng.integers(len(DATASETS))]
            data = f[name][()]
            data[int(rng.integers(len(data)))] = [np.nan, np.inf, 1e300, -5.0][rng.integers(4)]
            f[name][...] = data
        elif kind == "drop":
            del f[[*DATASETS, "calibration", "trials/t002"][rng.integers(6)]]
        else:
            del f["trials/t001/force_N"]
            f["trials/t001/force_N"] = (h5py.ExternalLink("other.h5", "/x") if rng.random()
                                        < 0.5 else h5py.SoftLink("/trials/t002/force_N"))
    return kind


def _check(path: Path) -> tuple[float, int, str]:
    tracemalloc.start()
    t0 = time.perf_counter()
    problems = validate_session(path)
    try:
        read_session(path)
        outcome = "read" if not problems else "read-but-invalid"
    except SessionFileError:
        outcome = "refused"
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return dt, peak, outcome if problems or outcome != "read" else "valid"


def main() -> None:
    rng = np.random.default_rng(2026)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        good = _good(tmp / "good.h5")
        base = [_check(good) for _ in range(5)]
        base_t = min(b[0] for b in base)
        base_m = max(b[1] for b in base)
        worst_t = (0.0, "")
        worst_m = (0, "")
        outcomes: dict[str, int] = {}
        for k in range(N_FILES):
            path = tmp / f"f{k}.h5"
            path.write_bytes(good.read_bytes())
            kind = _mutate(path, rng)
            dt, peak, outcome = _check(path)
            outcomes[outcome] = outcomes.get(outcome, 0) + 1
            if dt > worst_t[0]:
                worst_t = (dt, kind)
            if peak > worst_m[0]:
                worst_m = (peak, kind)
            os.unlink(path)
    print(f"bench_fuzz_sessions: {N_FILES} mutated session files tried; outcomes "
          + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    print(f"  worst time   {1000 * worst_t[0]:7.1f} ms ({worst_t[1]})   good file "
          f"{1000 * base_t:6.1f} ms   ratio {worst_t[0] / base_t:5.1f}x")
    print(f"  worst memory {worst_m[0] / 1e6:7.2f} MB ({worst_m[1]})   good file "
          f"{base_m / 1e6:6.2f} MB   ratio {worst_m[0] / base_m:5.1f}x")


if __name__ == "__main__":
    main()
