"""Kill tests: SIGKILL ``nmsid run --backend sim`` at random moments, then recover.

Every trial the process reported completed before the kill must be in the recovered file,
bit for bit (CRC of its force samples, as printed), and the file must validate. Most kills
hit forked children of this test process (``nmsid.cli.main`` runs in the child exactly as
the ``nmsid`` command would, without paying the interpreter start-up each time); two
kill a genuine ``python -m nmsid.cli run`` subprocess.
"""

import os
import re
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.session_log import PARTIAL_ABORT_REASON, journal_dir, recover
from tests.rig.forked_cli import fork_main as _fork_main

CONFIG = """
participant = "K01"
seed = 4
[protocol]
sE_levels = [0.4, 0.6, 0.8]
repeats = 2
steady_s = 0.5
chirp_s = 1.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""
N_TRIAL = 3000
# the progress line names the trial as the file does (issue 39 item 6: one numbering)
LINE = re.compile(r"^(t\d{3}) completed: sE (\S+) repeat (\d+) attempt (\d+) n \d+ "
                  r"crc ([0-9a-f]{8})")

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork / SIGKILL")


def _argv(cfg, out, *extra):
    return ["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
            "--no-identify", *extra]


def _printed(log_path):
    text = Path(log_path).read_text(errors="replace") if Path(log_path).exists() else ""
    return [(m.group(1), (m.group(2), int(m.group(3)), int(m.group(4))), m.group(5))
            for m in map(LINE.match, text.splitlines()) if m]


def _check_after_kill(path, printed):
    """Recover, then check every reported trial. Returns (n_trials, partial_recovered)."""
    if not path.exists() and not journal_dir(path).exists():
        assert not printed
        return 0, False
    rep = recover(path)
    marks = (".writing-", ".recovering-", ".journal.done-", ".journal.tmp-", ".lock")
    left = [p.name for p in path.parent.iterdir()
            if p.name.startswith(path.name) and any(m in p.name for m in marks)]
    assert left == [], left  # no temp file, half-removed journal or lock left behind
    if rep.action == "no-calibration":
        assert not printed and not path.exists()
        return 0, False
    assert validate_session(path) == [], validate_session(path)
    s = read_session(path)
    by_name = {t.name: t for t in s.trials}
    for name, (sE, repeat, attempt), crc in printed:
        t = by_name[name]   # the printed name is the file's group of that very trial
        assert t.completed and t.n_samples == N_TRIAL
        assert (f"{t.sE:.2f}", t.repeat, t.extra_attrs["attempt"]) == (sE, repeat, attempt)
        assert f"{zlib.crc32(t.force_N.astype('<f8').tobytes()):08x}" == crc
    for t in s.trials:
        if t.completed:
            assert t.n_samples == N_TRIAL and np.all(np.isfinite(t.force_N))
        else:               # the one trial the kill interrupted, closed by recovery
            assert t.abort_reason == PARTIAL_ABORT_REASON, t.abort_reason
    if rep.partial_recovered:
        assert s.trials[-1].abort_reason == PARTIAL_ABORT_REASON
    # recovering again changes nothing
    assert recover(path).action == "none"
    assert len(read_session(path).trials) == len(s.trials)
    return len(s.trials), rep.partial_recovered


def test_sigkill_at_random_moments_loses_nothing_completed(tmp_path):
    import nmsid.cli  # noqa: F401  (import once here, not in every child)
    import nmsid.cli.run_command  # noqa: F401
    import nmsid.rig.engine  # noqa: F401
    import nmsid.sim_backends.rig  # noqa: F401
    cfg = tmp_path / "k.toml"
    cfg.write_text(CONFIG)
    # a reference run: how long a whole session takes in a child here and now
    t0 = time.monotonic()
    pid = _fork_main(_argv(cfg, tmp_path / "ref.h5"), tmp_path / "ref.txt")
    _, status = os.waitpid(pid, 0)
    duration = time.monotonic() - t0
    assert os.waitstatus_to_exitcode(status) == 0, (tmp_path / "ref.txt").read_text()
    ref = read_session(tmp_path / "ref.h5")
    assert len(ref.trials) == 6 and not journal_dir(tmp_path / "ref.h5").exists()
    ref_crc = {t.name: f"{zlib.crc32(t.force_N.astype('<f8').tobytes()):08x}"
               for t in ref.trials}
    assert {n: c for n, _, c in _printed(tmp_path / "ref.txt")} == ref_crc

    rng = np.random.default_rng(20261122)
    outcomes = []
    for k in range(20):
        path = tmp_path / f"k{k:02d}.h5"
        log = tmp_path / f"k{k:02d}.txt"
        delay = rng.uniform(0.02, 1.0) * duration
        pid = _fork_main(_argv(cfg, path), log)
        time.sleep(delay)
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        printed = _printed(log)
        n, partial = _check_after_kill(path, printed)
        # same seed, same virtual participant: the data equal the reference run's
        for name, _, crc in printed:
            assert ref_crc[name] == crc
        outcomes.append((len(printed), n, partial))
    assert sum(1 for p, _, _ in outcomes if p > 0) >= 3, (outcomes, duration, [
        (tmp_path / f"k{k:02d}.txt").read_text()[-300:] for k in range(3)])

    # resume a killed session to the end: completed trials kept, the rest run
    victim = max(range(20), key=lambda k: (0 < outcomes[k][1] < 6, outcomes[k][1]))
    path = tmp_path / f"k{victim:02d}.h5"
    before = {t.name: t.force_N.copy() for t in read_session(path).trials if t.completed}
    pid = _fork_main(["run", "--backend", "sim", "--resume", str(path), "--no-identify"],
                     tmp_path / "resume.txt")
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, (tmp_path / "resume.txt").read_text()
    s = read_session(path)
    assert validate_session(path) == [] and not journal_dir(path).exists()
    done = {t.extra_attrs["schedule_index"] for t in s.trials if t.completed}
    assert done == set(range(6))
    for t in s.trials:
        if t.name in before:
            assert np.array_equal(t.force_N, before[t.name])


def test_sigkill_a_real_nmsid_process(tmp_path):
    cfg = tmp_path / "k.toml"
    cfg.write_text(CONFIG)
    rng = np.random.default_rng(7)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    for k in range(2):
        path = tmp_path / f"r{k}.h5"
        log = tmp_path / f"r{k}.txt"
        with open(log, "wb") as fh:
            proc = subprocess.Popen([sys.executable, "-m", "nmsid.cli", *_argv(cfg, path)],
                                    stdout=fh, stderr=subprocess.STDOUT, env=env,
                                    cwd=str(Path(__file__).resolve().parents[2]))
            t0 = time.monotonic()
            while not journal_dir(path).exists() and proc.poll() is None:
                if time.monotonic() - t0 > 60:
                    break
                time.sleep(0.005)
            time.sleep(rng.uniform(0.05, 1.2))
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        _check_after_kill(path, _printed(log))
