"""The session store with real processes and real signals: a reader holding the live
file of a real-time session, a second writer refused, a disk filled mid-session on a real
tmpfs (10 sizes), SIGKILL during calibration, at the end of the session and in recover."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.session_log import journal_dir
from tests.rig.forked_cli import fork_main as _fork_main
from tests.rig.forked_cli import wait_child as _wait

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONUNBUFFERED="1")
MARKS = (".writing-", ".recovering-", ".journal.done-", ".journal.tmp-", ".lock")

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork and signals")


def _config(tmp_path, *, levels=(0.5, 0.7), repeats=2, steady_s=0.3, chirp_s=0.5,
            rest_s=0.2):
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'participant = "S01"\nseed = 2\n[protocol]\nsE_levels = {list(levels)}\n'
                   f'repeats = {repeats}\nsteady_s = {steady_s}\nchirp_s = {chirp_s}\n'
                   f'rest_s = {rest_s}\n[calibration]\nmanual = {{Iemin_mA = 2.0, '
                   'Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n')
    return cfg


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()
                  if any(m in p.name for m in MARKS) or p.name.endswith(".tmp"))


def _nmsid(*argv, **kw):
    return subprocess.Popen([sys.executable, "-m", "nmsid.cli", *map(str, argv)], cwd=str(ROOT),
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


def _kill_self():
    os.kill(os.getpid(), signal.SIGKILL)


# -- a reader and a second writer during a real-time session ------------------------------
def test_reader_across_trial_ends_and_second_writers_refused_during_a_realtime_run(tmp_path):
    cfg = _config(tmp_path, levels=(0.4, 0.6, 0.8), steady_s=0.5, chirp_s=0.7)  # ~9 s
    out = tmp_path / "live.h5"
    run = _nmsid("run", "--backend", "sim", "--realtime", "--config", cfg, "--out", out,
                 "--no-identify")
    t0 = time.monotonic()
    while not out.exists() and run.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.02)
    assert out.exists(), run.communicate()
    # a process that holds the live file open (h5py default open) for seconds
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, h5py\nf = h5py.File(sys.argv[1])\n"
         "n = [len(f['trials']) for _ in range(25) if time.sleep(0.1) is None]\n"
         "print(min(n), max(n)); f.close()", str(out)],
        stdout=subprocess.PIPE, text=True)
    # second writers and a validate while the session runs: forked (no interpreter start
    # up to wait for, so they surely meet the live writer), real processes all the same
    import nmsid.cli  # noqa: F401
    import nmsid.cli.run_command  # noqa: F401
    import nmsid.cli.validate_command  # noqa: F401
    others = {name: (_fork_main(argv, tmp_path / f"{name}.txt"), tmp_path / f"{name}.txt")
              for name, argv in (("recover", ["recover", out]),
                                 ("resume", ["run", "--backend", "sim", "--resume", out,
                                             "--no-identify"]),
                                 ("validate", ["validate", out]))}
    results = {name: (_wait(pid), log) for name, (pid, log) in others.items()}
    live_at_end = run.poll() is None
    seen = set()
    while run.poll() is None and time.monotonic() - t0 < 60:
        with h5py.File(out, "r") as f:  # this test process opens and reads too
            seen.add(len(f["trials"]))
            for name in f["trials"]:
                assert f["trials"][name]["force_N"].shape[0] > 0
        time.sleep(0.05)
    text = run.communicate()
    assert run.returncode == 0, text
    assert live_at_end, "the session ended before the second writers were refused"
    assert len(seen) >= 2, seen  # the reads spanned trial ends
    lo_hi = holder.communicate(timeout=30)[0].split()
    assert holder.returncode == 0 and lo_hi[0] == lo_hi[1]  # its snapshot stayed whole
    for name in ("recover", "resume"):
        (code, signalled), log = results[name]
        out_text = log.read_text().strip().splitlines()
        assert (code, signalled) == (2, False), out_text
        assert f"is being written by process {run.pid}" in out_text[-1]
    (code, _), log = results["validate"]
    assert code == 0 and f"live session: written now by process {run.pid}" in log.read_text()
    assert validate_session(out) == []
    assert len(read_session(out).trials) == 6
    assert _leftovers(tmp_path) == [] and not journal_dir(out).exists()


# -- SIGKILL at chosen moments -----------------------------------------------------------
def _fault_in(module, name, after=False):
    """A fault that SIGKILLs the process when ``module.name`` is called (or returns)."""
    def plant():
        import importlib
        mod = importlib.import_module(module)
        owner, attr = (mod, name) if "." not in name else (
            getattr(mod, name.split(".")[0]), name.split(".")[1])
        orig = getattr(owner, attr)

        def wrapped(*a, **k):
            if not after:
                _kill_self()
            result = orig(*a, **k)
            _kill_self()
            return result
        setattr(owner, attr, wrapped)
    return plant


@pytest.mark.parametrize("moment", ["calibration", "end of session", "recover publish"])
def test_sigkill_at_a_chosen_moment_loses_nothing_and_leaves_no_temp_file(tmp_path, moment):
    cfg = _config(tmp_path, levels=(0.5,), repeats=2, rest_s=0.0)
    out = tmp_path / "k.h5"
    argv = ["run", "--backend", "sim", "--config", cfg, "--out", out, "--no-identify"]
    if moment == "calibration":  # calibration journaled, file not yet published
        fault = _fault_in("nmsid.rig.session_log", "publish_image")
    elif moment == "end of session":  # journal renamed to .done-PID, not yet removed
        fault = _fault_in("nmsid.rig.session_log", "shutil.rmtree")
    else:  # the first trial journaled, not yet in the file: recover must append it
        fault = _fault_in("nmsid.protocols.session_writer", "SessionWriter.append_trials")
    code, signalled = _wait(_fork_main(argv, tmp_path / "run.txt", fault))
    assert signalled, (tmp_path / "run.txt").read_text()
    if moment == "recover publish":  # SIGKILL recover as it renames its first file
        code, signalled = _wait(_fork_main(["recover", out], tmp_path / "rec.txt",
                                           _fault_in("nmsid.protocols.session_publish",
                                                     "os.replace")))
        assert signalled, (tmp_path / "rec.txt").read_text()
    code, signalled = _wait(_fork_main(["recover", out], tmp_path / "rec2.txt"))
    assert (code, signalled) == (0, False) or moment == "calibration", \
        (tmp_path / "rec2.txt").read_text()
    code, signalled = _wait(_fork_main(["run", "--backend", "sim", "--resume", out,
                                        "--no-identify"], tmp_path / "res.txt"))
    assert (code, signalled) == (0, False), (tmp_path / "res.txt").read_text()
    s = read_session(out)
    assert validate_session(out) == []
    assert {t.extra_attrs["schedule_index"] for t in s.trials if t.completed} == {0, 1}
    assert _leftovers(tmp_path) == [] and not journal_dir(out).exists()


# -- a disk filled mid-session on a real tmpfs ---------------------------------------------
@pytest.fixture
def small_fs(tmp_path):
    mnt = tmp_path / "fs"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"mounting a tmpfs is not permitted here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


LEAVE_FREE_BYTES = [0, 4096, 16384, 40960, 81920, 131072, 200704, 307200, 512000, 819200]


def _fill(folder: Path, leave_bytes: int) -> Path:
    filler = folder / "filler.bin"
    st = os.statvfs(folder)
    size = st.f_bavail * st.f_frsize - leave_bytes
    with open(filler, "wb") as fh:
        if size > 0:
            try:
                os.posix_fallocate(fh.fileno(), 0, size)
            except OSError:
                pass
    return filler


def test_disk_filled_mid_session_at_ten_sizes(tmp_path, small_fs):
    cfg = _config(tmp_path, levels=(0.4, 0.6, 0.8), repeats=2, steady_s=0.25, chirp_s=0.5,
                  rest_s=0.0)
    import nmsid.cli  # noqa: F401 (imported once; the forked children share it)
    import nmsid.rig.engine  # noqa: F401
    import nmsid.sim_backends.rig  # noqa: F401
    outcomes = []
    for k, leave in enumerate(LEAVE_FREE_BYTES):
        folder = small_fs / f"s{k}"
        folder.mkdir()
        out = folder / "d.h5"
        log = tmp_path / f"run{k}.txt"
        pid = _fork_main(["run", "--backend", "sim", "--config", cfg, "--out", out,
                          "--no-identify"], log)
        trigger = journal_dir(out) / f"trial-{1 + k % 4:04d}.npz"
        t0 = time.monotonic()
        while not trigger.exists() and time.monotonic() - t0 < 30:
            if os.waitpid(pid, os.WNOHANG) != (0, 0):
                pytest.fail(f"size {k}: the run ended before the disk was filled:\n"
                            + log.read_text())
            time.sleep(0.001)
        # the session is held while the disk fills (a fast-clock session would otherwise
        # often finish first): the disk is full exactly after this trial's journal entry
        os.kill(pid, signal.SIGSTOP)
        try:
            filler = _fill(small_fs, leave)
        finally:
            os.kill(pid, signal.SIGCONT)
        code, signalled = _wait(pid)
        text = log.read_text()
        assert not signalled, (k, text)
        outcomes.append(code)
        if code != 0:  # ended by the full disk: one line naming the file
            last = text.strip().splitlines()[-1]
            # the session file, or the journal entry being written when space ran out
            named = (f"nmsid: error: {out}: disk full",
                     f"nmsid: error: {journal_dir(out)}{os.sep}trial-")
            assert code == 2 and last.startswith(named) and ": disk full: " in last, (k, text)
            assert "Traceback" not in text
        problems = validate_session(out) if out.exists() else ["missing"]
        if problems == []:  # called valid: then every dataset reads back
            read_session(out)
        # recover on the still full disk: no signal; works or one line saying what it needs
        code, signalled = _wait(_fork_main(["recover", out], tmp_path / f"rf{k}.txt"))
        rtext = (tmp_path / f"rf{k}.txt").read_text()
        assert not signalled and "Traceback" not in rtext, (k, rtext)
        assert code == 0 or "disk full" in rtext.strip().splitlines()[-1], (k, rtext)
        outcomes[-1] = (outcomes[-1], code)
        filler.unlink()
        code, signalled = _wait(_fork_main(["recover", out], tmp_path / f"r{k}.txt"))
        assert code in (0, 1) and not signalled, (tmp_path / f"r{k}.txt").read_text()
        code, signalled = _wait(_fork_main(["run", "--backend", "sim", "--resume", out,
                                            "--no-identify"], tmp_path / f"res{k}.txt"))
        assert (code, signalled) == (0, False), (k, (tmp_path / f"res{k}.txt").read_text())
        s = read_session(out)
        assert validate_session(out) == []
        assert {t.extra_attrs["schedule_index"] for t in s.trials if t.completed} == \
            set(range(6)), k
        assert _leftovers(folder) == [] and not journal_dir(out).exists(), k
    # most sizes really ended the session on the full disk (the rest finished first: the
    # journal is deflated and the file published once, so small sessions fit more often)
    assert sum(1 for run, _ in outcomes if run == 2) >= 5, outcomes
    print("disk-full outcomes (run exit, recover-on-full-disk exit):", outcomes)
