"""Around the analysis of ``nmsid identify``: start-up imports, reading the session file,
and writing the outputs, each against its floor measured in the same process.

    python bench/bench_identify_io.py                   # records a 45-trial session first
    python bench/bench_identify_io.py --session S.h5 --runs 5

* **reading**: :func:`read_session` of the rE and force datasets (every contract check of
  the fatal-only validation, the value checks, the events) against plain h5py reading of
  the same datasets and every attribute with no check at all (``dict(obj.attrs)``,
  ``dataset[()]``): the price of the checks. Repeated in one process, and as the first
  read of a fresh process (the one read ``nmsid identify`` makes: a new process's
  allocator and HDF5's free lists are empty, so it costs more). Target (issue 30):
  <= 0.05 s.
* **start-up**: a fresh process importing the handler (``import
  nmsid.cli.identify_command``) against one importing only the libraries it cannot do
  without (numpy, h5py, pydantic's settings machinery) and against ``python -c pass``.
  Target: <= 0.11 s.
* **outputs**: everything ``run_identification`` does after the fits (model selection,
  twin, SHA-256 of the session, seven files) with the fits replaced by their results,
  against writing the same bytes with ``Path.write_bytes``.

Times are the process's CPU time (user + sys), medians: a loaded machine stretches wall
time far more than CPU time. The session is the one ``bench_identify_process.py`` records
(15 sE x 3 repeats, 2000 Hz, 15 s trials).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (ROOT, HERE):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from workers import child_env  # noqa: E402

from nmsid.cli import limit_blas_threads  # noqa: E402
from nmsid.protocols.os_platform import is_windows  # noqa: E402

READ_TARGET_S = 0.05
IMPORT_TARGET_S = 0.11
_FLOOR_IMPORTS = ("import numpy, h5py; from pydantic import Field, StrictFloat, "
                  "model_validator; from pydantic.dataclasses import dataclass")


def _arg(name: str, default: str | None) -> str | None:
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default


def _cpu_of(fn, runs: int) -> tuple[float, Any]:
    """Median CPU seconds of ``fn()`` over ``runs`` calls (after one warm-up) and its result."""
    result = fn()
    times = []
    for _ in range(runs):
        t0 = time.process_time()
        result = fn()
        times.append(time.process_time() - t0)
    return statistics.median(times), result


def _plain_read(path: Path, datasets: tuple[str, ...]) -> int:
    """The floor: the same datasets and every attribute read by plain h5py, no checks."""
    import h5py
    n = 0
    with h5py.File(path, "r") as f:
        dict(f.attrs)
        dict(f["calibration"].attrs)
        events = f["events"]
        for key in events:
            dict(events[key].attrs)
        trials = f["trials"]
        for name in trials:
            g = trials[name]
            dict(g.attrs)
            for key in datasets:
                n += g[key][()].size
    return n


def _process_cpu(code: str, runs: int) -> float:
    """Median CPU seconds (user + sys) of ``python -c code`` processes (nan on Windows,
    whose os.times does not count children)."""
    env = child_env()
    env.pop("PYTHONDONTWRITEBYTECODE", None)     # cached bytecode, as an installed copy
    # one BLAS thread, as nmsid identify starts itself: OpenBLAS's thread per core costs
    # ~0.1 s of CPU at numpy's import alone, in ours and the floor alike
    limit_blas_threads(env)
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT)
    cpus = []
    for _ in range(runs):
        before = os.times()
        subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT)
        after = os.times()
        cpus.append(float("nan") if is_windows() else
                    (after.children_user - before.children_user)
                    + (after.children_system - before.children_system))
    return statistics.median(cpus)


_FIRST_READ = """
import sys, time
sys.path.insert(0, sys.argv[2])
import numpy, h5py
import nmsid.cli.identify_command
from nmsid.protocols.session_file import read_session
from bench_identify_io import _plain_read
t0 = time.process_time()
if sys.argv[3] == "ours":
    read_session(sys.argv[1], datasets=("rE", "force_N"))
else:
    _plain_read(sys.argv[1], ("rE", "force_N"))
print(time.process_time() - t0)
"""


def _first_read_cpu(session: Path, which: str, runs: int) -> float:
    """Median CPU seconds of the first read in a fresh process (what ``nmsid identify``
    pays: its one read meets a new process's empty allocator and HDF5 free lists)."""
    env = child_env()
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    limit_blas_threads(env)                      # as nmsid identify starts itself
    out = [float(subprocess.run([sys.executable, "-c", _FIRST_READ, str(session), str(HERE),
                                 which], check=True, env=env, cwd=ROOT, capture_output=True,
                                text=True).stdout.split()[-1]) for _ in range(runs)]
    return statistics.median(out)


def _outputs(session: Path, tmp: Path, runs: int) -> tuple[float, float, float]:
    """(ours, floor, of which SHA-256) CPU seconds of the run after the fits."""
    import nmsid.analysis.run as run_mod
    from nmsid.analysis.identify import identify_session
    from nmsid.analysis.settings import IdentificationSettings
    from nmsid.analysis.twin import file_sha256

    settings = IdentificationSettings()
    result = identify_session(str(session), settings)
    real = run_mod.identify_session
    run_mod.identify_session = lambda src, s: result       # the fits' results, as computed
    counter = iter(range(10 ** 6))
    try:
        ours, out = _cpu_of(lambda: run_mod.run_identification(
            [str(session)], tmp / f"out{next(counter)}", settings, figures=False), runs)
    finally:
        run_mod.identify_session = real
    files = [(p, p.read_bytes()) for p in out.files]
    floor_dir = tmp / "floor"
    floor_dir.mkdir()

    def write_plain() -> None:
        for p, data in files:
            (floor_dir / p.name).write_bytes(data)

    floor, _ = _cpu_of(write_plain, runs)
    sha, _ = _cpu_of(lambda: file_sha256(session), runs)
    return ours, floor, sha


def main() -> None:
    from nmsid.protocols.session_file import read_session

    runs = int(_arg("--runs", "5") or 5)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        given = _arg("--session", None)
        if given is None:
            from bench_identify_process import make_session
            session = make_session(tmp)
        else:
            session = Path(given)
        wanted = ("rE", "force_N")
        ours, s = _cpu_of(lambda: read_session(session, datasets=wanted), runs)
        plain, n = _cpu_of(lambda: _plain_read(session, wanted), runs)
        n_trials = len(s.trials)
        first = _first_read_cpu(session, "ours", runs)
        first_plain = _first_read_cpu(session, "plain", runs)
        out_ours, out_floor, sha = _outputs(session, tmp, runs)
        start = _process_cpu("import nmsid.cli.identify_command", runs)
        floor = _process_cpu(_FLOOR_IMPORTS, runs)
        empty = _process_cpu("pass", runs)
        size_MB = session.stat().st_size / 1e6     # inside the block: a made session goes
    load = "n/a" if is_windows() else "{:.2f} / {:.2f}".format(*os.getloadavg()[:2])
    print(f"nmsid identify around the analysis: {size_MB:.0f} MB session, "
          f"{n_trials} trials; CPU times (user + sys), medians of {runs}; load average {load}")
    print(f"  read_session(rE, force_N): {ours * 1e3:.0f} ms, x{ours / plain:.2f} plain h5py "
          f"reading of the same {n / 1e6:.1f} M samples and every attribute without checks "
          f"({plain * 1e3:.0f} ms)   target <= {READ_TARGET_S * 1e3:.0f} ms  "
          f"{'OK' if ours <= READ_TARGET_S else 'missed'}")
    print(f"  the same, first read of a fresh process (what nmsid identify pays): "
          f"{first * 1e3:.0f} ms, x{first / first_plain:.2f} plain h5py ({first_plain * 1e3:.0f}"
          f" ms)   target <= {READ_TARGET_S * 1e3:.0f} ms  "
          f"{'OK' if first <= READ_TARGET_S else 'missed'}")
    print(f"  start-up: import of the handler {start:.3f} s, x{start / floor:.2f} importing "
          f"numpy + h5py + pydantic alone ({floor:.3f} s); python -c pass {empty:.3f} s   "
          f"target <= {IMPORT_TARGET_S:.2f} s  {'OK' if start <= IMPORT_TARGET_S else 'missed'}")
    print(f"  outputs: selection, twin and 7 files after the fits {out_ours * 1e3:.0f} ms "
          f"(SHA-256 of the session {sha * 1e3:.0f} ms of it), x{out_ours / out_floor:.1f} "
          f"writing the same bytes ({out_floor * 1e3:.1f} ms)")


if __name__ == "__main__":
    main()
