"""Kill-and-damage campaign (issue 26, 7): recovery keeps every good trial.

Each run: a fast-clock simulated session (``nmsid run --backend sim``, a real
subprocess) is killed with SIGKILL at a random moment (0-0.15 s after a random number of
trial ends, 0 meaning after the journal appears: from calibration to the end); then one journal
entry or the journal's ``header.json`` is damaged (overwritten with random bytes, truncated, or
deleted); then ``nmsid recover`` and ``nmsid run --resume`` run to the end. Counted:

* trials completed before the kill (a completed trial in the journal or the file), and
  of those, the ones still intact in the file or the journal after the damage;
* trials kept: intact ones found, sample for sample (CRC), in the final file;
* trials stimulated twice: schedule indexes with more than one completed trial in the
  final file (a completed trial run again by the resume);
* tracebacks in any command's output, and final files that do not validate.

Target: every intact completed trial kept, none stimulated twice, 0 tracebacks.

    python bench/bench_recovery_campaign.py          # 30 runs, 2 campaigns side by side
    python bench/bench_recovery_campaign.py --runs 5 --jobs 1
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.journal import JournalEntryError, load_trial_npz, trial_digest

CONFIG = ('participant = "S01"\nseed = {seed}\n[protocol]\nsE_levels = {levels}\n'
          'repeats = 2\nsteady_s = 0.25\nchirp_s = 0.5\nrest_s = 0.0\n[calibration]\n'
          'manual = {{Iemin_mA = 2.0, Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}}\n')
DAMAGES = ("overwrite entry", "truncate entry", "delete entry", "overwrite header",
           "truncate header", "delete header")


@dataclass
class RunResult:
    """One kill-and-damage run."""

    kill_after_s: float
    damage: str
    completed: int = 0
    intact: int = 0
    kept: int = 0
    twice: int = 0
    tracebacks: int = 0
    valid: bool = False
    all_done: bool = False
    resumable: bool = True
    """False when the damage left nothing to resume from: no session file yet (killed
    before calibration ended) and its journal header damaged or deleted, so the
    configuration is gone; recover and resume must then say so in one line."""
    notes: list[str] = field(default_factory=list)


def _identity(t) -> tuple:
    return (int(t.extra_attrs.get("schedule_index", -1)), trial_digest(t))


def _completed_now(out: Path) -> set[tuple]:
    """Completed trials in the journal and the file at this moment."""
    found: set[tuple] = set()
    jdir = out.with_name(out.name + ".journal")
    for p in sorted(jdir.glob("trial-*.npz")) if jdir.is_dir() else []:
        try:
            t = load_trial_npz(p)
        except JournalEntryError:
            continue
        if t.status == "completed":
            found.add(_identity(t))
    try:
        found |= {_identity(t) for t in read_session(out).trials if t.status == "completed"}
    except Exception:  # noqa: BLE001
        return found  # a killed writer's file may be missing or damaged: the journal's
    return found


def _damage(out: Path, what: str, rng: random.Random) -> str:
    jdir = out.with_name(out.name + ".journal")
    if what.endswith("entry"):
        entries = sorted(jdir.glob("trial-*.npz")) if jdir.is_dir() else []
        if not entries:
            what = what.replace("entry", "header")
        else:
            target = rng.choice(entries)
    if what.endswith("header"):
        target = jdir / "header.json"
        if not target.exists():
            return f"{what}: nothing to damage (no journal header)"
    data = target.read_bytes()
    if what.startswith("overwrite"):
        target.write_bytes(os.urandom(max(16, len(data))))
    elif what.startswith("truncate"):
        target.write_bytes(data[: len(data) // 3])
    else:
        target.unlink()
    return f"{what}: {target.name}"


def _start(argv: list, log: Path, env: dict) -> subprocess.Popen:
    fh = open(log, "w", encoding="utf-8")  # noqa: SIM115 (closed by the caller's wait)
    return subprocess.Popen([sys.executable, "-m", "nmsid.cli", *map(str, argv)],
                            cwd=str(ROOT), env=env, stdout=fh, stderr=subprocess.STDOUT)


def one_run(folder: Path, k: int, rng: random.Random, *, levels=(0.4, 0.6, 0.8),
            max_kill_s: float = 0.15, launch=None) -> RunResult:
    """Run, kill, damage, recover, resume one session in ``folder``.

    ``launch(argv, log_path, env)`` starts ``nmsid argv`` and returns an object with
    ``pid``, ``poll()`` and ``wait(timeout)`` like ``subprocess.Popen`` (default: a new
    interpreter; the test forks one that has nmsid imported already)."""
    _nmsid = launch or _start
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    cfg = folder / f"c{k}.toml"
    cfg.write_text(CONFIG.format(seed=k + 1, levels=list(levels)), encoding="utf-8")
    out = folder / f"S{k}.h5"
    n_trials = 2 * len(levels)
    after_entries = rng.randrange(n_trials)
    res = RunResult(kill_after_s=rng.uniform(0.0, max_kill_s), damage="")
    proc = _nmsid(["run", "--backend", "sim", "--config", cfg, "--out", out,
                   "--no-identify"], folder / f"run{k}.txt", env)
    jdir = out.with_name(out.name + ".journal")
    t0 = time.monotonic()  # the random moment: a random delay after a random trial end
    while proc.poll() is None and time.monotonic() - t0 < 120 and not (
            (jdir / "header.json").exists()
            and len(list(jdir.glob("trial-*.npz"))) >= after_entries):
        time.sleep(0.002)
    res.notes.append(f"killed {res.kill_after_s:.2f} s after {after_entries} trial end(s)")
    try:
        code = proc.wait(timeout=res.kill_after_s)
        res.notes.append(f"the session ended before the kill (exit {code})")
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    completed = _completed_now(out)
    res.completed = len(completed)
    res.damage = _damage(out, rng.choice(DAMAGES), rng) \
        if out.with_name(out.name + ".journal").is_dir() else "none (journal removed)"
    intact = _completed_now(out)
    res.intact = len(completed & intact)
    logs = [folder / f"run{k}.txt"]
    for step, argv in (("recover", ["recover", out]),
                       ("resume", ["run", "--backend", "sim", "--resume", out,
                                   "--no-identify"])):
        if not out.exists() and not out.with_name(out.name + ".journal").exists():
            res.notes.append(f"{step}: nothing on disk (killed before the session started)")
            res.resumable = bool(completed)  # nothing was recorded: nothing to resume
            break
        log = folder / f"{step}{k}.txt"
        code = _nmsid(argv, log, env).wait(timeout=600)
        logs.append(log)
        if code not in (0, 2):
            res.notes.append(f"{step} exit {code}")
        if step == "recover" and code == 2:
            last = log.read_text(encoding="utf-8").strip().splitlines()[-1]
            res.notes.append("recover: " + last[:160])
            if not out.exists() and "header.json: is" in last and not completed:
                res.resumable = False  # the run then must refuse in one line too
    res.tracebacks = sum(p.read_text(encoding="utf-8", errors="replace").count("Traceback")
                         for p in logs if p.exists())
    if out.exists():
        res.valid = validate_session(out) == []
        if res.valid:
            trials = read_session(out).trials
            final = {_identity(t) for t in trials if t.status == "completed"}
            res.kept = len((completed & intact) & final)
            done = [int(t.extra_attrs["schedule_index"]) for t in trials
                    if t.status == "completed"]
            res.twice = len(done) - len(set(done))
            res.all_done = set(done) == set(range(2 * len(levels)))
    return res


def damaged(r: RunResult) -> bool:
    """The run reached the damage step (the session was killed with its journal)."""
    return bool(r.damage) and not r.damage.startswith("none") and \
        "nothing to damage" not in r.damage


def campaign(n_runs: int, folder: Path, seed: int = 26, **kw) -> list[RunResult]:
    """Runs until ``n_runs`` of them were killed with a journal to damage (a kill that
    lands after the clean end removed the journal does not count; at most 3 x n_runs)."""
    rng = random.Random(seed)
    out: list[RunResult] = []
    k = 0
    while sum(damaged(r) for r in out) < n_runs and k < 3 * n_runs:
        out.append(one_run(folder, k, rng, **kw))
        k += 1
    return out


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    n_runs = int(argv[argv.index("--runs") + 1]) if "--runs" in argv else 30
    jobs = max(1, int(argv[argv.index("--jobs") + 1]) if "--jobs" in argv else 2)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as tmp:
        # ``jobs`` campaigns side by side (threads: the work is in the nmsid processes
        # each starts), each with its own folder and seed, n_runs between them
        shares = [n_runs // jobs + (i < n_runs % jobs) for i in range(jobs)]
        folders = [Path(tmp) / f"campaign{i}" for i in range(jobs)]
        for f in folders:
            f.mkdir()
        with ThreadPoolExecutor(jobs) as ex:
            parts = list(ex.map(lambda i: campaign(shares[i], folders[i], seed=26 + i),
                                range(jobs)))
        results = [r for part in parts for r in part]
    print(f"bench_recovery_campaign: {len(results)} runs, {sum(map(damaged, results))} of "
          f"them killed with a journal to damage (SIGKILL at a random moment of a "
          f"6-trial fast-clock sim session, one damage, recover, run --resume; {jobs} "
          f"campaign(s) side by side, seeds {26}-{26 + jobs - 1}), "
          f"{time.perf_counter() - t0:.0f} s")
    for k, r in enumerate(results):
        print(f"  run {k:2d}: {r.damage:36s} completed "
              f"{r.completed}, intact {r.intact}, kept {r.kept}, twice {r.twice}, "
              f"tracebacks {r.tracebacks}, valid {r.valid}, schedule done {r.all_done}"
              + (f" [{'; '.join(r.notes)}]" if r.notes else ""))
    completed = sum(r.completed for r in results)
    intact = sum(r.intact for r in results)
    kept = sum(r.kept for r in results)
    twice = sum(r.twice for r in results)
    tb = sum(r.tracebacks for r in results)
    invalid = sum(1 for r in results if r.resumable and not r.valid)
    unresumable = [r for r in results if not r.resumable]
    print(f"  trials completed before the kill: {completed}; intact after the damage: "
          f"{intact}; kept in the recovered file: {kept} ({kept}/{intact}); lost to the "
          f"damage (their only copy): {completed - intact}")
    print(f"  stimulated twice: {twice}; tracebacks: {tb}; final files invalid: {invalid}; "
          f"schedules completed: {sum(r.all_done for r in results)}/{len(results)}; "
          f"nothing to resume (killed before any trial, the configuration only in the "
          f"damaged header): {len(unresumable)}")
    ok = kept == intact and twice == 0 and tb == 0 and invalid == 0
    print(f"  target (every intact trial kept, none twice, 0 tracebacks): "
          f"{'met' if ok else 'missed'}")


if __name__ == "__main__":
    main()
