"""Tests that bite (issue 29, 5) for the store: every file that lands under a session's
name (the session file, each journal entry) was fsynced as that very file and arrived by a
rename, never written in place; a file that appears after any check is never overwritten;
recovery compares the file's samples with the journal's.

Written against behaviour (what the file system sees), not against the store's code: the
spy records which inodes were fsynced, which arrived by rename / link, and which names were
opened for writing, whatever module does it.
"""

from __future__ import annotations

import builtins
import errno
import os
import stat

import h5py
import numpy as np
import pytest

from nmsid.protocols.session_file import (
    Calibration,
    SessionExistsError,
    SessionWriter,
    Trial,
    read_session,
)
from nmsid.rig.session_log import SessionLog, journal_dir, recover


class DurabilitySpy:
    """What the file system was asked to do: fsynced inodes, inodes renamed / linked into
    place (by destination), and paths opened for writing."""

    def __init__(self, monkeypatch):
        self.fsynced: set[tuple[int, int]] = set()
        self.arrived: dict[str, tuple[int, int]] = {}
        self.opened_for_write: list[str] = []
        self.dir_synced_after: dict[tuple[int, int], int] = {}
        real_fsync, real_replace, real_rename = os.fsync, os.replace, os.rename
        real_link, real_open, real_os_open = os.link, builtins.open, os.open

        def ident(st):
            return st.st_dev, st.st_ino

        def fsync(fd):
            st = os.fstat(fd if isinstance(fd, int) else fd.fileno())
            self.fsynced.add(ident(st))
            if stat.S_ISDIR(st.st_mode):  # a folder made durable: after which arrivals?
                self.dir_synced_after[ident(st)] = len(self.arrived)
            return real_fsync(fd)

        def moved(real):
            def move(src, dst, *a, **kw):
                src, dst = os.fspath(src), os.path.abspath(os.fspath(dst))
                if os.path.isdir(src):  # a folder built aside, renamed in: its files too
                    before = {n: ident(os.stat(os.path.join(src, n))) for n in os.listdir(src)
                              if os.path.isfile(os.path.join(src, n))}
                else:
                    before = {"": ident(os.stat(src))} if os.path.isfile(src) else {}
                out = real(src, dst, *a, **kw)
                for name, st in before.items():
                    key = os.path.join(dst, name) if name else dst
                    self.arrived.pop(key, None)  # re-inserted: its order is this rename's
                    self.arrived[key] = st
                return out
            return move

        def open_(file, mode="r", *a, **kw):
            if isinstance(file, (str, os.PathLike)) and any(c in mode for c in "wax+"):
                self.opened_for_write.append(os.path.abspath(os.fspath(file)))
            return real_open(file, mode, *a, **kw)

        def os_open(path, flags, *a, **kw):
            if flags & (os.O_WRONLY | os.O_RDWR):
                self.opened_for_write.append(os.path.abspath(os.fspath(path)))
            return real_os_open(path, flags, *a, **kw)

        monkeypatch.setattr(os, "fsync", fsync)
        monkeypatch.setattr(os, "replace", moved(real_replace))
        monkeypatch.setattr(os, "rename", moved(real_rename))
        monkeypatch.setattr(os, "link", moved(real_link))
        monkeypatch.setattr(builtins, "open", open_)
        monkeypatch.setattr(os, "open", os_open)

    def landed_durably(self, path) -> bool:
        """``path`` arrived by a rename or link of a file that had been fsynced, and its
        folder was fsynced after that rename (so the new name survives a power cut)."""
        p = os.path.abspath(os.fspath(path))
        st = os.stat(p)
        folder = os.stat(os.path.dirname(p))
        order = list(self.arrived)
        return self.arrived.get(p) == (st.st_dev, st.st_ino) and \
            (st.st_dev, st.st_ino) in self.fsynced and \
            self.dir_synced_after.get((folder.st_dev, folder.st_ino), -1) > \
            max(i for i, k in enumerate(order) if k == p)


def _trial(i, n=400):
    rng = np.random.default_rng(i)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rng.random(n),
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i})


def _log(path):
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    return log


@pytest.mark.posix_only('the folder fsync is POSIX (Windows cannot fsync a directory handle); the '
                        'Windows publish is tested in tests/rig/test_store_windows.py')
def test_each_published_session_file_was_fsynced_and_renamed_into_place(tmp_path,
                                                                         monkeypatch):
    spy = DurabilitySpy(monkeypatch)
    path = tmp_path / "P01.h5"
    w = SessionWriter.create(path, participant="P01")
    assert spy.landed_durably(path)
    w.write_calibration(Calibration(1, 9, 1.5, 10))
    assert spy.landed_durably(path)
    w.append_trial(_trial(0))
    assert spy.landed_durably(path)
    assert str(path.absolute()) not in spy.opened_for_write   # never written in place


@pytest.mark.posix_only('the folder fsync is POSIX (Windows cannot fsync a directory handle); the '
                        'Windows journal is tested in tests/rig/test_store_windows.py')
def test_each_journal_entry_was_fsynced_and_renamed_never_written_in_place(tmp_path,
                                                                           monkeypatch):
    spy = DurabilitySpy(monkeypatch)
    path = tmp_path / "P01.h5"
    log = _log(path)
    for i in range(2):
        log.end_trial(_trial(i))
    jdir = journal_dir(path)
    entries = [p for p in jdir.iterdir() if p.is_file() and not p.name.endswith(".tmp")
               and p.suffix in (".npz", ".json")]
    assert len([p for p in entries if p.name.startswith("trial-")]) == 2
    for entry in entries:
        assert spy.landed_durably(entry), entry.name
        assert str(entry.absolute()) not in spy.opened_for_write, entry.name
    log.close()


def test_a_session_file_that_appears_after_the_check_is_never_overwritten(tmp_path,
                                                                          monkeypatch):
    path = tmp_path / "P01.h5"
    path.write_bytes(b"someone else's data")
    # the race: whatever the writer asks before writing, the path looks free...
    monkeypatch.setattr(os.path, "lexists", lambda p: False)
    monkeypatch.setattr(os.path, "exists", lambda p: False)
    with pytest.raises(SessionExistsError):
        SessionWriter.create(path, participant="P01")
    # ...and the file that appeared meanwhile is untouched
    assert path.read_bytes() == b"someone else's data"


def test_recovery_compares_the_files_samples_with_the_journals(tmp_path):
    path = tmp_path / "P01.h5"
    log = _log(path)
    trials = [_trial(i) for i in range(2)]
    for t in trials:
        log.end_trial(t)
    log.close()                       # a kill: the journal stays
    with h5py.File(path, "a") as f:   # the file's copy of t001 now differs (valid checksums)
        f["trials/t001/force_N"][...] = f["trials/t001/force_N"][()] + 1.0
    rep = recover(path)
    assert rep.action != "none"       # a difference is never called "nothing to recover"
    s = read_session(path)
    assert np.array_equal(s.trials[0].force_N, trials[0].force_N)  # the journal's samples


@pytest.mark.parametrize("fault, raised", [(OSError(errno.ENOSPC, "No space left"), "disk"),
                                           (KeyboardInterrupt(), "interrupt")])
def test_a_failed_publish_leaves_the_file_and_no_temp(tmp_path, monkeypatch, fault, raised):
    from nmsid.protocols.errors import DiskFullError
    path = tmp_path / "P01.h5"
    w = SessionWriter.create(path, participant="P01")
    before = path.read_bytes()

    real_fsync, calls = os.fsync, []

    def fail(fd):  # the first fsync fails (the file's data); the rest work
        calls.append(fd)
        if len(calls) == 1:
            raise fault
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(DiskFullError if raised == "disk" else KeyboardInterrupt):
        w.write_calibration(Calibration(1, 9, 1.5, 10))
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["P01.h5"]


@pytest.mark.parametrize("fault, raised", [(OSError(errno.ENOSPC, "No space left"), "disk"),
                                           (KeyboardInterrupt(), "interrupt")])
def test_a_failed_journal_entry_leaves_no_temp(tmp_path, monkeypatch, fault, raised):
    from nmsid.protocols.errors import DiskFullError
    path = tmp_path / "P01.h5"
    log = _log(path)
    jdir = journal_dir(path)
    before = sorted(p.name for p in jdir.iterdir())

    real_fsync, calls = os.fsync, []

    def fail(fd):  # the first fsync fails (the file's data); the rest work
        calls.append(fd)
        if len(calls) == 1:
            raise fault
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(DiskFullError if raised == "disk" else KeyboardInterrupt):
        log.end_trial(_trial(0))
    monkeypatch.undo()
    after = sorted(p.name for p in jdir.iterdir())
    assert not [n for n in after if n.endswith(".tmp")], after
    assert [n for n in after if n.startswith("trial-")] == \
        [n for n in before if n.startswith("trial-")]
    log.close()
