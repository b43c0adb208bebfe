"""The session file's store: readers never disturb the writer, one writer per session,
recovery salvages what it can and leaves nothing behind, checksums catch bit flips."""

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from nmsid.protocols.errors import DiskFullError, SessionLockedError
from nmsid.protocols.session_file import (
    Calibration,
    SessionFileError,
    Trial,
    read_session,
    validate_session,
)
from nmsid.protocols.session_lock import SessionLock, live_writer
from nmsid.rig.session_log import SessionLog, journal_dir, recover

ROOT = Path(__file__).resolve().parents[2]


def _trial(i, n=400, wrench=False):
    rng = np.random.default_rng(i)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rng.random(n),
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i},
                 wrench=rng.normal(size=(n, 6)) if wrench else None,
                 sync=(rng.random(n) > 0.5) * 5.0 if wrench else None)


def _log(path):
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    return log


def leftovers(folder: Path) -> list[str]:
    """Temp files, half-removed journals and lock files left in ``folder``."""
    marks = (".writing-", ".recovering-", ".journal.done-", ".journal.tmp-", ".lock")
    return sorted(p.name for p in folder.iterdir() if any(m in p.name for m in marks)
                  or p.name.endswith(".tmp"))


@pytest.mark.posix_only('POSIX: a reader keeps its snapshot while the writer renames a new version '
                        'over it; Windows refuses that rename, and the held file is published '
                        'later (tests/rig/test_store_windows.py)')
def test_a_reader_holding_the_file_open_never_disturbs_the_writer(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    with h5py.File(path, "r") as reader:  # h5py's default open, with HDF5's file lock
        seen = len(reader["trials"])
        for i in range(1, 4):
            log.end_trial(_trial(i))
            # the reader keeps its consistent snapshot (the file as published with the
            # calibration; trials are journaled, and published at the end)
            assert len(reader["trials"]) == seen == 0
            assert reader["calibration"].attrs["Iemax_mA"] == 9
        assert len(read_session(path).trials) == 0
        assert len(list(journal_dir(path).glob("trial-*.npz"))) == 4
        assert log.finish() is True  # publishing while the reader holds its snapshot
        assert len(reader["trials"]) == 0
    assert validate_session(path) == [] and len(read_session(path).trials) == 4
    assert leftovers(tmp_path) == []


def _hold_lock_in_child(path: Path) -> subprocess.Popen:
    code = ("import sys, time; from protocols.session_lock import SessionLock; "
            "SessionLock.acquire(sys.argv[1], 'test holder'); print('held', flush=True); "
            "time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], cwd=str(ROOT),
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


@pytest.mark.posix_only('a child process holds a POSIX flock while the test follows Windows; the '
                        'Windows lock is tested against FakeMsvcrt '
                        '(tests/protocols/test_session_lock.py)')
def test_recover_and_resume_refuse_a_live_writer_naming_it_and_a_killed_one_leaves_no_lock(
        tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    log.close()  # as if the writer had died here (the journal stays)
    proc = _hold_lock_in_child(path)
    try:
        info = live_writer(path)
        assert info is not None and info.pid == proc.pid and info.command == "test holder"
        for attempt in (lambda: recover(path), lambda: SessionLog.resume(path)):
            with pytest.raises(SessionLockedError) as err:
                attempt()
            assert f"process {proc.pid} on host" in str(err.value)
            assert str(path) in str(err.value)
        with pytest.raises(SessionLockedError):  # a second run on that path
            SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                              backend="test", schedule_json="[]")
    finally:
        proc.kill()
        proc.wait()
    assert live_writer(path) is None  # the kernel dropped the lock with the process
    assert recover(path).n_trials == 1
    assert leftovers(tmp_path) == []


def test_recover_salvages_every_readable_entry_and_reports_a_truncated_one(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    trials = [_trial(i) for i in range(4)]
    for t in trials:
        log.end_trial(t)
    log.close()
    jdir = journal_dir(path)
    victim = jdir / "trial-0002.npz"
    victim.write_bytes(victim.read_bytes()[:300])  # truncated by a crash
    path.unlink()  # the file is gone too: only the journal is left
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.n_trials == 3
    assert len(rep.unreadable) == 1 and rep.unreadable[0].startswith("trial-0002.npz")
    assert "trial-0002.npz" in rep.summary() and "unreadable" in rep.summary()
    s = read_session(path)
    assert [round(t.sE, 6) for t in s.trials] == [round(trials[i].sE, 6) for i in (0, 2, 3)]
    assert np.array_equal(s.trials[2].force_N, trials[3].force_N)
    assert validate_session(path) == []
    # the journal is consistent again: resume continues it
    log2, _ = SessionLog.resume(path)
    assert len(log2.trials) == 3
    log2.end_trial(_trial(9))
    assert log2.finish() is True
    assert len(read_session(path).trials) == 4
    assert leftovers(tmp_path) == []


def test_recover_removes_leftovers_of_killed_writers(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    log.close()
    for name in ("P01.h5.writing-99999", "P01.h5.recovering-99998"):
        (tmp_path / name).write_bytes(b"x" * 10)
    (tmp_path / "P01.h5.journal.done-99997").mkdir()
    (tmp_path / "P01.h5.journal.done-99997" / "trial-0001.npz").write_bytes(b"x")
    (journal_dir(path) / "trial-0002.npz.tmp").write_bytes(b"x")
    other = tmp_path / "P02.h5.writing-99999"  # another session's: not ours to touch
    other.write_bytes(b"y")
    rep = recover(path)
    assert rep.leftovers_removed == 4
    assert leftovers(tmp_path) == ["P02.h5.writing-99999"]


def test_a_renamed_file_mentions_its_orphaned_journal(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    log.close()
    renamed = tmp_path / "renamed.h5"
    os.rename(path, renamed)
    rep = recover(renamed)
    assert rep.action == "none"
    text = rep.summary()
    assert "P01.h5.journal" in text and "rename the file back to P01.h5" in text


def test_the_trial_in_progress_keeps_wrench_and_sync(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    t = _trial(0, n=300, wrench=True)
    log.begin_trial(t)
    log.append_chunk(force_N=t.force_N[:200], rE=t.rE[:200], I_ext_mA=t.I_ext_mA[:200],
                     I_flex_mA=t.I_flex_mA[:200], wrench=t.wrench[:200], sync=t.sync[:200])
    log.close()  # killed mid-trial
    rep = recover(path)
    assert rep.partial_recovered and rep.partial_samples == 200
    kept = read_session(path).trials[-1]
    assert kept.status == "aborted"
    assert np.array_equal(kept.wrench, t.wrench[:200])
    assert np.array_equal(kept.sync, t.sync[:200])


def _flip_a_bit_in(path: Path, data: np.ndarray) -> None:
    raw = bytearray(path.read_bytes())
    at = raw.find(np.ascontiguousarray(data).tobytes()[:64])
    assert at > 0
    raw[at + 20] ^= 0x04
    path.write_bytes(bytes(raw))


def test_a_bit_flip_in_the_data_is_reported_not_called_valid(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    t = _trial(0)
    log.end_trial(t)
    assert log.finish()
    _flip_a_bit_in(path, t.force_N)  # random normals do not deflate: stored as they are
    problems = validate_session(path)
    assert len(problems) == 1 and problems[0].startswith("/trials/t001/force_N is damaged")
    with pytest.raises(SessionFileError, match="damaged"):
        read_session(path)


def test_a_full_disk_before_the_write_changes_nothing_and_says_so(tmp_path, monkeypatch):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    before = path.read_bytes()
    import nmsid.protocols.session_publish as pub
    monkeypatch.setattr(pub, "free_bytes", lambda folder: 1000)
    log.end_trial(_trial(1))  # journaled (and in memory): the file is published at the end
    with pytest.raises(DiskFullError) as err:
        log._writer.publish("writing trial sE 0.35 repeat 1")
    text = str(err.value)
    assert text.startswith(f"{path}: disk full") and "MB free" in text and "\n" not in text
    # the published file is unchanged; only the live writer's lock file is there
    assert path.read_bytes() == before and leftovers(tmp_path) == ["P01.h5.lock"]
    # the session's end then keeps the journal (logged), nothing is lost
    assert log.finish() is False and path.read_bytes() == before
    assert len(list(journal_dir(path).glob("trial-*.npz"))) == 2


def test_check_space_names_folder_need_and_free(tmp_path, monkeypatch):
    path = tmp_path / "P01.h5"
    log = _log(path)
    import nmsid.rig.session_log as sl
    monkeypatch.setattr(sl, "free_bytes", lambda folder: 2_000_000)
    with pytest.raises(DiskFullError) as err:
        log.check_space(50_000_000)
    assert str(tmp_path) in str(err.value) and "51.05 MB" in str(err.value) \
        and "2.00 MB free" in str(err.value)
    log.close()


def test_lock_is_reentrant_in_one_process_and_released_at_the_end(tmp_path):
    path = tmp_path / "P01.h5"
    a = SessionLock.acquire(path, "a")
    b = SessionLock.acquire(path, "b")
    assert a is b
    b.release()
    assert (tmp_path / "P01.h5.lock").exists()
    a.release()
    assert not (tmp_path / "P01.h5.lock").exists()
    # a lock file left by a dead writer (nobody holds its flock) means: no writer
    (tmp_path / "P01.h5.lock").write_text(json.dumps({"pid": 1, "host": "x"}))
    assert live_writer(path) is None
    SessionLock.acquire(path, "c").release()


@pytest.mark.parametrize("seed, participant, expected", [
    (2 ** 63, "P01", "seed 9223372036854775808 is not valid: an integer in [0, 2**63 - 1]"),
    (3, "P01\n", "participant code 'P01\\n' is not valid")])
def test_a_seed_or_code_the_file_cannot_hold_is_refused_before_anything_is_written(
        tmp_path, seed, participant, expected):
    path = tmp_path / "P01.h5"
    with pytest.raises(SessionFileError) as err:
        SessionLog.create(path, participant=participant, config_json="{}", seed=seed,
                          backend="test", schedule_json="[]")
    assert expected in str(err.value)
    assert list(tmp_path.iterdir()) == []  # no journal, no lock file, no session file


@pytest.mark.posix_only('a child process holds a POSIX flock while the test follows Windows; the '
                        'Windows lock is tested against FakeMsvcrt '
                        '(tests/protocols/test_session_lock.py)')
def test_reading_a_live_file_says_so(tmp_path, caplog):
    path = tmp_path / "P01.h5"
    log = _log(path)
    log.end_trial(_trial(0))
    log.close()
    proc = _hold_lock_in_child(path)
    try:
        with caplog.at_level("WARNING"):
            s = read_session(path)
    finally:
        proc.kill()
        proc.wait()
    assert len(s.trials) == 1
    assert any(f"live session: written now by process {proc.pid}" in r.getMessage()
               and "1 trial(s) so far" in r.getMessage() for r in caplog.records)
