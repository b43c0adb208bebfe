"""A whole simulated session, headless, on the fast clock: time and accuracy.

For a few virtual participants: calibration ramps + the 45-trial schedule through the
engine (interlock, journal, HDF5), the file checked with ``validate_session``, then the
identification (``analysis.identify.identify_session``) compared with the participant's
truth ``participant.true_parameters(sE, calibration)`` at every sE. Goals: the session
under 3 s on the fast clock (issue 30; 10 s before), every parameter within 2 % at every
sE. The baseline beside it is the same session's identification, timed in the same
process (what the session exists for).

Then the same session as a user runs it, a whole process timed from outside:
``nmsid run --backend sim --participant P01 --outdir D --no-identify`` (median wall and CPU
time of 3 processes, and their largest own peak resident memory: on Linux the child's own
``VmHWM``, since wait4's ``ru_maxrss`` keeps this process's high-water mark across fork and
exec; elsewhere on POSIX ``ru_maxrss``; none on Windows), with start-up
shown separately (a process that only imports the command's handler, beside
``python -c pass``). Goal: < 3 s whole process (issue 30).

    python bench/bench_session.py
    python bench/bench_session.py --seeds 1     # one in-process session (quick look)
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, Path(__file__).resolve().parent):   # nmsid; bench/ (workers)
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from workers import child_env  # noqa: E402

from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.protocols.os_platform import is_windows  # noqa: E402
from nmsid.protocols.session_file import read_session, validate_session  # noqa: E402
from nmsid.rig.engine import Engine, TripPolicy  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402


def _one(seed: int, tmp: Path) -> dict:
    from nmsid.analysis.identify import identify_session

    rig = make_sim_rig(seed=seed)
    cfg = config_from_dict({"participant": f"B{seed:02d}", "seed": seed,
                            "protocol": {"rest_s": 0.0}})
    path = tmp / f"B{seed:02d}.h5"
    t0, c0 = time.perf_counter(), time.process_time()
    summary = Engine(cfg, rig, path, trip_policy=TripPolicy.END_SESSION).run()
    t_session, cpu_session = time.perf_counter() - t0, time.process_time() - c0
    valid = validate_session(path) == []
    t1 = time.perf_counter()
    result = identify_session(path)
    t_ident = time.perf_counter() - t1
    cal = read_session(path, load_data=False).calibration
    ref = rig.participant.calibration
    cal_ok = (cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA, cal.Ifmax_mA) == (
        ref.Iemin_mA, ref.Iemax_mA, ref.Ifmin_mA, ref.Ifmax_mA)
    worst = {"Kp": 0.0, "wn_rad_s": 0.0, "zeta": 0.0}
    for lv in result.levels:
        truth = rig.participant.true_parameters(lv.sE, cal)._asdict()
        for name in worst:
            got = getattr(lv.fit, name) if lv.fit is not None else np.nan
            worst[name] = max(worst[name], abs(got / truth[name] - 1) * 100)
    return {"seed": seed, "trials": summary.n_completed, "session_s": t_session,
            "cpu_s": cpu_session,
            "valid": valid, "cal_ok": cal_ok, "identify_s": t_ident, "levels":
            len(result.levels), **{f"err_{k}": v for k, v in worst.items()}}


def _process(cmd: list[str]) -> tuple[float, float]:
    """(wall s, CPU s) of one process; CPU is nan on Windows (os.times does not count
    children there)."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=child_env(), cwd=ROOT, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = float("nan") if is_windows() else (
        after.children_user - before.children_user
        + after.children_system - before.children_system)
    return wall, cpu


def _process_peak(cmd: list[str]) -> tuple[float, float, float]:
    """(wall s, CPU s, peak resident MB) of this one process: ``os.wait4`` reports that
    child's own usage (POSIX; on Windows the wall time and nan, nan). Not RUSAGE_CHILDREN:
    in a full bench run that is the largest child of any earlier benchmark."""
    if is_windows():
        return _process(cmd)[0], float("nan"), float("nan")
    env = child_env()
    hwm = None
    if Path("/proc/self/status").is_file() and cmd[1:3] == ["-m", "nmsid"]:
        # Linux: wait4's ru_maxrss keeps the parent's high-water mark across fork + exec
        # (this process, after its in-process sessions: ~690 MB), so the child reports its
        # own mm's VmHWM at exit instead
        fd, hwm = tempfile.mkstemp(suffix=".hwm")
        os.close(fd)
        env["NMSID_BENCH_HWM"] = hwm
        cmd = [cmd[0], "-c", _HWM_WRAPPER, *cmd[2:]]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
    _, status, ru = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise subprocess.CalledProcessError(proc.returncode, cmd)
    kb = ru.ru_maxrss / (1024 if sys.platform == "darwin" else 1)
    if hwm is not None:
        text = Path(hwm).read_text(encoding="utf-8").strip()
        os.unlink(hwm)
        kb = float(text) if text else float("nan")
    return wall, ru.ru_utime + ru.ru_stime, kb / 1024


_HWM_WRAPPER = """
import atexit, os, runpy, sys
def _hwm():
    with open("/proc/self/status", encoding="utf-8") as f:
        kb = next(line.split()[1] for line in f if line.startswith("VmHWM:"))
    with open(os.environ["NMSID_BENCH_HWM"], "w", encoding="utf-8") as f:
        f.write(kb)
atexit.register(_hwm)
sys.argv = sys.argv[1:]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
"""
"""Runs ``python -m MODULE ARGS`` and writes the process's own peak resident memory
(``VmHWM`` of /proc/self/status, kB) at exit to the file named by ``NMSID_BENCH_HWM``."""


def whole_process(tmp: Path, runs: int = 3) -> None:
    """The session as a user runs it (median of ``runs`` processes), and the start-up of
    such a process."""
    rows = []
    for k in range(runs):
        out = tmp / f"process-{k}"
        out.mkdir()
        rows.append(_process_peak([sys.executable, "-m", "nmsid", "run", "--backend", "sim",
                                   "--participant", "P01", "--outdir", str(out),
                                   "--no-identify"]))
    wall = float(np.median([r[0] for r in rows]))
    cpu = float(np.median([r[1] for r in rows]))
    peak = max(r[2] for r in rows)
    start = [_process([sys.executable, "-c", "import nmsid.cli.run_command"])[0]
             for _ in range(3)]
    bare = [_process([sys.executable, "-c", "pass"])[0] for _ in range(3)]
    t_start, t_bare = sorted(start)[1], sorted(bare)[1]
    met = "< 3" if wall < 3.0 else "missed"
    print(f"\nWhole process: nmsid run --backend sim --participant P01 --no-identify "
          f"(15 sE x 3 repeats, fast clock), median of {runs} processes "
          f"(wall {min(r[0] for r in rows):.2f}-{max(r[0] for r in rows):.2f} s)")
    print(f"{'wall s':>7s} {'cpu s':>6s} {'goal':>6s} {'peak MB':>8s} {'start-up s':>10s} "
          f"{'python s':>8s} {'session - start-up s':>20s} {'start-up share':>14s}")
    print(f"{wall:7.2f} {cpu:6.2f} {met:>6s} {peak:8.0f} {t_start:10.2f} {t_bare:8.2f} "
          f"{wall - t_start:20.2f} {t_start / wall:14.2f}")
    print("(start-up: median of 3 processes that only import the command's handler; "
          "python: median of 3 `python -c pass`"
          + ("; PYTHONDONTWRITEBYTECODE is set: the project's modules are compiled at every "
             "start" if os.environ.get("PYTHONDONTWRITEBYTECODE") else "") + ")")


def filters_vs_scipy(trials: int = 20) -> None:
    """The simulator's filters (protocols/lti_kernels.py, public scipy.signal since issue
    38) against plain scipy.signal calls, on the participants' range at 2000 Hz: a 15 s trial (30000
    samples) of the 2nd-order model and of the 3rd-order cascade with an activation lag, each
    continued from a past (``lfilter`` from ``lfiltic``'s states); time per trial and the largest
    difference, relative to the trial's largest output. Plus the import of each."""
    t0 = time.perf_counter()
    import scipy.signal as ss  # the baseline's own import, timed
    t_import_scipy = time.perf_counter() - t0
    from nmsid.protocols.lti_kernels import lfilter_history
    from nmsid.sim_backends.filters import dynamics_zoh
    rng = np.random.default_rng(30)
    print("\nSimulator filters, lfilter_history (protocols/lti_kernels.py, on public "
          "scipy.signal) vs plain scipy.signal calls (lfilter + lfiltic), "
          f"{trials} random participants per order, 30000-sample trials at 2000 Hz")
    print(f"{'order':>5s} {'ours ms':>9s} {'scipy ms':>9s} {'ratio':>6s} "
          f"{'max |diff| / max |y|':>21s} {'goal':>8s}")
    per_trial = []
    for lag in (False, True):
        t_np = t_sp = worst = 0.0
        for _ in range(trials):
            wn, zeta = rng.uniform(2.0, 60.0), rng.uniform(0.2, 1.5)
            tau = rng.uniform(0.005, 0.08) if lag else 0.0
            b, a = dynamics_zoh(wn, zeta, tau, 2000.0)
            n = len(a) - 1
            x = rng.uniform(0.0, 1.0, 30000)
            xp, yp = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
            c0 = time.perf_counter()
            y = lfilter_history(b, a, x, xp, yp)
            c1 = time.perf_counter()
            y_ref = ss.lfilter(b, a, x, zi=ss.lfiltic(b, a, yp, xp))[0]
            c2 = time.perf_counter()
            t_np += c1 - c0
            t_sp += c2 - c1
            worst = max(worst, float(np.max(np.abs(y - y_ref)) / np.max(np.abs(y_ref))))
        per_trial.append(t_np / trials - t_sp / trials)
        print(f"{3 if lag else 2:5d} {1e3 * t_np / trials:9.2f} {1e3 * t_sp / trials:9.2f} "
              f"{t_np / t_sp:6.1f} {worst:21.1e} {'< 1e-9' if worst < 1e-9 else 'missed':>8s}")
    print(f"import: scipy.signal {t_import_scipy:.2f} s in this process (near 0 if an earlier "
          "benchmark loaded it), which a session never pays; the filters cost a 45-trial "
          f"session {45 * max(max(per_trial), 0.0):.2f} s more than scipy.signal's at most")


def main(seeds=(0, 1, 2)) -> None:
    logging.disable(logging.WARNING)
    tmp = Path(tempfile.mkdtemp(prefix="nmsid-bench-session-"))
    print("Full simulated session (calibration + 45 trials), fast clock; identification vs "
          "truth (max |error| over the 15 sE levels)")
    try:
        import os
        print(f"machine load (1 min): {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
              "'session s' is wall time, 'cpu s' the process's CPU time (all threads)")
    except (AttributeError, OSError):
        pass
    head = (f"{'seed':>4s} {'trials':>6s} {'session s':>9s} {'cpu s':>6s} {'goal':>6s} "
            f"{'valid':>5s} "
            f"{'cal=ref':>7s} {'identify s':>10s} {'ratio':>6s} {'Kp %':>6s} {'wn %':>6s} "
            f"{'zeta %':>6s} {'goal':>5s}")
    print(head)
    for seed in seeds:
        r = _one(seed, tmp)
        met = "< 3" if r["session_s"] < 3.0 else "missed"
        print(f"{r['seed']:4d} {r['trials']:6d} {r['session_s']:9.2f} {r['cpu_s']:6.2f} "
              f"{met:>6s} "
              f"{str(r['valid']):>5s} {str(r['cal_ok']):>7s} {r['identify_s']:10.2f} "
              f"{r['session_s'] / r['identify_s']:6.1f} "
              f"{r['err_Kp']:6.2f} {r['err_wn_rad_s']:6.2f} {r['err_zeta']:6.2f} "
              f"{'< 2':>5s}", flush=True)
    whole_process(tmp)
    filters_vs_scipy()


if __name__ == "__main__":
    n_seeds = int(sys.argv[sys.argv.index("--seeds") + 1]) if "--seeds" in sys.argv else 3
    main(tuple(range(n_seeds)))
