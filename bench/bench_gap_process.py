"""``nmsid gap`` as a whole process on recorded 45-trial sessions, against ``nmsid identify``
of the same file run the same way.

    python bench/bench_gap_process.py                 # template session, then physics
    python bench/bench_gap_process.py --runs 3 --no-physics

Two sessions, each recorded by ``nmsid run --backend sim`` (15 sE x 3 repeats, 2000 Hz):
the template participant (the paper's second-order model; nothing for the diagnosis to
find) and, when the ``mujoco`` extra is installed, the musculoskeletal one (MyoSuite's
elbow; the template leaves a gap, so the muscle twin is fitted too: that part is the
analysis engineer's, reported here as its own figure from the report's ``fit_s``).
Every run is a new Python process timed from outside (start, imports, read, QC, diagnosis,
report, twin; ``--no-figures``), median over the runs, with its CPU time (user + sys) since a
loaded machine stretches wall time. Start-up is shown separately (a process that only
imports the handler). The fairest baseline in the same form is ``nmsid identify
--no-figures`` of the same file: the same reading and preprocessing, one fit per level.
Targets (issue 30): < 1.5 s on the template session, < 6 s on the physics session.

Where the time goes is printed per stage from one more process that runs the handler's
steps itself (``_STAGES``: CPU seconds of each, the interpreter's own start excluded), so a
missed target names the part that missed it.
"""

from __future__ import annotations

import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for _p in (ROOT, Path(__file__).resolve().parent):   # nmsid; bench/ (workers)
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from workers import child_env  # noqa: E402

from nmsid.protocols.os_platform import is_windows  # noqa: E402


def _run(cmd: list[str]) -> tuple[float, float]:
    """(wall s, CPU s of the child) of one process; the CPU time is NaN on Windows, whose
    ``os.times`` does not count children."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=child_env(), cwd=ROOT, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = os.times()
    if is_windows():
        return wall, float("nan")
    return wall, (after.children_user - before.children_user) + \
        (after.children_system - before.children_system)


def _median(cmds: list[list[str]]) -> tuple[float, float]:
    runs = [_run(c) for c in cmds]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def record(tmp: Path, model: str) -> Path:
    out = tmp / model
    subprocess.run([sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim",
                    "--participant", "G", "--outdir", str(out), "--seed", "12",
                    "--participant-model", model, "--no-identify", "--quiet"],
                   check=True, env=child_env(), cwd=ROOT, stdout=subprocess.DEVNULL)
    return next(out.glob("G-*.h5"))


#: Run in a child process: the steps of ``nmsid gap --no-figures`` one by one (as
#: ``analysis.gap.api.run_gap`` takes them), printing each one's CPU seconds as JSON.
_STAGES = """
import json, sys, tempfile, time
t = time.process_time()
out = {}
def mark(name):
    global t
    now = time.process_time()
    out[name] = now - t
    t = now
import nmsid.cli.gap_command
from nmsid.analysis.data_bounds import check_session_data
from nmsid.analysis.gap.data import GAP_DATASETS, load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose
from nmsid.analysis.gap.report import write_outputs
from nmsid.analysis.qc import assess_session
from nmsid.protocols.session_file import read_session
mark("imports")
s = read_session(sys.argv[1], datasets=GAP_DATASETS)
check_session_data(s, s.path)
mark("read")
excluded = assess_session(s).excluded()
mark("qc")
data = load_session(s, None, excluded=excluded)
mark("preprocess")
diag = diagnose(data, GapSettings())
mark("diagnosis")
m = diag.muscle_tried
out["muscle_twin_wall"] = float(getattr(m, "fit_s", 0.0) or 0.0) if m is not None else 0.0
with tempfile.TemporaryDirectory() as d:
    write_outputs(diag, d, s.calibration, plots=False)
mark("report")
out["candidates_fitted"] = len(diag.candidates) + len(diag.pairs)
print(json.dumps(out))
"""


def stages(session: Path) -> dict:
    """CPU seconds of each step of the diagnosis, from one child process."""
    r = subprocess.run([sys.executable, "-c", _STAGES, str(session)], check=True,
                       env=child_env(), cwd=ROOT, capture_output=True, text=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def _arg(name: str, default: int) -> int:
    return int(sys.argv[sys.argv.index(name) + 1]) if name in sys.argv else default


def measure(session: Path, tmp: Path, runs: int, target_s: float, label: str) -> None:
    py = sys.executable
    gap = [py, "-m", "nmsid.cli", "gap", str(session), "--no-figures", "--out"]
    ident = [py, "-m", "nmsid.cli", "identify", str(session), "--no-figures", "--out"]
    _run(gap + [str(tmp / f"{label}-warm")])                  # page cache, .pyc files
    gap_wall, gap_cpu = _median([gap + [str(tmp / f"{label}-gap{i}")] for i in range(runs)])
    id_wall, id_cpu = _median([ident + [str(tmp / f"{label}-id{i}")] for i in range(runs)])
    start_wall, start_cpu = _median([[py, "-c", "import nmsid.cli.gap_command"]] * runs)
    report = json.loads((tmp / f"{label}-gap0" / "gap_report.json").read_text("utf-8"))
    muscle = report.get("muscle_twin") or {}
    size_MB = session.stat().st_size / 1e6
    print(f"{label} session ({size_MB:.0f} MB, {report['n_trials']} trials): verdict "
          f"{report['verdict']}, best effect {report['best_effect']}")
    print(f"  nmsid gap --no-figures: median {gap_wall:.2f} s wall (CPU {gap_cpu:.2f} s) over "
          f"{runs} runs   target < {target_s:g} s  {'OK' if gap_wall < target_s else 'missed'}")
    print(f"    start-up (import of the handler): {start_wall:.2f} s (CPU {start_cpu:.2f} s); "
          f"diagnosis in the process itself: {report['elapsed_s']:.2f} s"
          + (f", of it the muscle twin {muscle['fit_s']:.2f} s" if muscle.get("fit_s")
             else ""))
    print(f"  baseline nmsid identify --no-figures of the same file: median {id_wall:.2f} s "
          f"(CPU {id_cpu:.2f} s); gap / identify x{gap_wall / id_wall:.1f}")
    st = stages(session)
    order = ("imports", "read", "qc", "preprocess", "diagnosis", "report")
    total = sum(st[k] for k in order)
    print("  where the CPU goes (one process, s): " + ", ".join(
        f"{k} {st[k]:.2f}" for k in order) + f"; sum {total:.2f} + interpreter start "
          f"(of the diagnosis: the muscle twin {st['muscle_twin_wall']:.2f} s wall; "
          f"{st['candidates_fitted']} candidate models fitted"
          + (", none needed: the nominal gap is within noise" if
             report.get("candidates_not_fitted") else "") + ")")


def main() -> None:
    runs = _arg("--runs", 3)
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"nmsid gap, whole process; load average {load[0]:.1f} / {load[1]:.1f} on "
          f"{os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        measure(record(tmp, "template"), tmp, runs, 1.5, "template")
        if "--no-physics" in sys.argv:
            return
        if importlib.util.find_spec("mujoco") is None:
            print("physics session: skipped (the 'mujoco' extra is not installed)")
            return
        measure(record(tmp, "musculoskeletal"), tmp, runs, 6.0, "physics")


if __name__ == "__main__":
    main()
