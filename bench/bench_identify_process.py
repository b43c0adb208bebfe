"""``nmsid identify`` as a whole process on a 45-trial simulated session, against a plain
discretised least-squares fit run as a whole process too.

    python bench/bench_identify_process.py              # 7 runs of ours, 1 plain
    python bench/bench_identify_process.py --runs 3 --plain-runs 2

The session is recorded by the simulator (``nmsid run --backend sim``, 15 sE x 3 repeats,
2000 Hz). Every run is a new Python process (start, imports, read, fit, select, write;
figures or not) timed from outside, the way a user waits for it. The plain baseline is
``bench/plain_identify_process.py``: the same reader and preprocessing, then
``scipy.optimize.least_squares`` over a ZOH-discretised model per level (3 starts), at the
recorded 2000 Hz (``--raw``, the plain approach of ``bench_identification`` too: it fits
what was recorded). It is also timed on our 200 Hz fitting data, a plain fitter that
borrows our decimation, and that ratio is printed as well.
Targets (issue 12): with figures < 1.0 s median, and >= 5x faster than the plain process.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"]
                                     if env.get("PYTHONPATH") else "")
    return env


def _wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=_env(), cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def make_session(tmp: Path) -> Path:
    subprocess.run([sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim",
                    "--participant", "B", "--outdir", str(tmp), "--seed", "12"],
                   check=True, env=_env(), cwd=ROOT, stdout=subprocess.DEVNULL)
    return next(tmp.glob("B-*.h5"))


def _arg(name: str, default: int) -> int:
    return int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default


def main() -> None:
    runs, plain_runs = _arg("--runs", 7), _arg("--plain-runs", 1)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        session = make_session(tmp)
        ident = [sys.executable, "-m", "nmsid.cli", "identify", str(session), "--out"]
        _wall(ident + [str(tmp / "warm")])                  # page cache, .pyc files
        with_fig, without = [], []
        for i in range(runs):                              # interleaved: same load for both
            with_fig.append(_wall(ident + [str(tmp / f"fig{i}")]))
            without.append(_wall(ident + [str(tmp / f"nofig{i}"), "--no-figures"]))
        plain_cmd = [sys.executable, str(HERE / "plain_identify_process.py"), str(session)]
        plain = [_wall(plain_cmd + ["--raw"]) for _ in range(plain_runs)]
        plain_200 = [_wall(plain_cmd) for _ in range(max(plain_runs, 3))]
        size_MB = session.stat().st_size / 1e6
    med_fig, med_nofig, med_plain, med_200 = (statistics.median(v) for v in
                                              (with_fig, without, plain, plain_200))
    ratio = med_plain / med_fig
    load = os.getloadavg()
    print(f"nmsid identify, whole process, 45-trial simulated session ({size_MB:.0f} MB, "
          f"15 sE x 3, 2000 Hz); load average {load[0]:.1f} / {load[1]:.1f} on "
          f"{os.cpu_count()} cores")
    print(f"  with figures:    median {med_fig:.2f} s over {runs} runs (fastest "
          f"{min(with_fig):.2f} s, slowest {max(with_fig):.2f} s)   target < 1.0 s  "
          f"{'OK' if med_fig < 1.0 else 'MISSED'}")
    print(f"  --no-figures:    median {med_nofig:.2f} s over {runs} runs (figures cost "
          f"{med_fig - med_nofig:+.2f} s)")
    print(f"  plain discretised least squares (least_squares over ZOH lfilter, 3 starts, "
          f"same reader and preprocessing, 2000 Hz as recorded): median {med_plain:.2f} s "
          f"over {plain_runs} run(s)")
    print(f"  ratio plain / identify with figures: {ratio:.1f}x   target >= 5x  "
          f"{'OK' if ratio >= 5 else 'MISSED'}")
    print(f"  the same plain fitter on our 200 Hz fitting data (borrowing our decimation): "
          f"median {med_200:.2f} s over {len(plain_200)} runs, ratio {med_200 / med_fig:.1f}x")


if __name__ == "__main__":
    main()
