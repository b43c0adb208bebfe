"""Durability of publishing (protocols/session_publish.py) and of journal entries
(rig/journal.py): each step in its order, spied on. A kill between two steps leaves the old
version or the new one, never a torn one (fsync BEFORE the rename; the folder fsynced
after it, on POSIX)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

import nmsid.protocols.session_publish as pub
from nmsid.protocols import os_platform
from nmsid.protocols.session_file import SessionExistsError, Trial
from nmsid.rig import journal


def _spy(monkeypatch, module_os):
    """Record fsync (of a file or a folder), replace, link and rename, in order."""
    calls: list[tuple[str, str]] = []
    real = {name: getattr(os, name) for name in ("fsync", "replace", "link", "rename")}

    def fsync(fd):
        kind = "dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file"
        calls.append(("fsync", kind))
        return real["fsync"](fd)

    def wrap(name):
        def f(a, b, *args, **kw):
            calls.append((name, os.path.basename(os.fspath(b))))
            return real[name](a, b, *args, **kw)
        return f
    monkeypatch.setattr(module_os, "fsync", fsync)
    for name in ("replace", "link", "rename"):
        monkeypatch.setattr(module_os, name, wrap(name))
    return calls


@pytest.mark.posix_only('the folder fsync is POSIX (Windows cannot fsync a directory handle)')
def test_publish_fsyncs_the_new_version_before_replacing_then_the_folder(tmp_path,
                                                                        monkeypatch):
    path = tmp_path / "s.h5"
    path.write_bytes(b"old")
    calls = _spy(monkeypatch, pub.os)
    with os_platform.forced("posix"):
        pub.publish_image(path, b"new version")
    assert calls == [("fsync", "file"), ("replace", "s.h5"), ("fsync", "dir")]
    assert path.read_bytes() == b"new version"
    assert not list(tmp_path.glob("*.writing-*"))


def test_a_new_file_is_linked_never_replaced_and_never_overwrites(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    calls = _spy(monkeypatch, pub.os)
    with os_platform.forced("posix"):
        pub.publish_image(path, b"first", exclusive=True)
    assert calls[:2] == [("fsync", "file"), ("link", "s.h5")]
    # a file that appears between the check and the publish is never overwritten
    with monkeypatch.context() as m, os_platform.forced("posix"), \
            pytest.raises(SessionExistsError):
        m.setattr(pub.os.path, "lexists", lambda p: False)  # the check passed, then...
        pub.publish_image(path, b"second", exclusive=True)
    import shutil

    from nmsid.testing.windows_emulation import emulate_windows
    real_usage = shutil.disk_usage(tmp_path)

    class _Path:  # os.path for session_publish only: its check passed, then...
        def __getattr__(self, name):
            return (lambda p: False) if name == "lexists" else getattr(os.path, name)

    class _Os:
        path = _Path()

        def __getattr__(self, name):
            return getattr(os, name)
    with emulate_windows(), pytest.raises(SessionExistsError):
        monkeypatch.setattr(shutil, "disk_usage", lambda p: real_usage)  # (needs statvfs)
        monkeypatch.setattr(pub, "os", _Os())
        pub.publish_image(path, b"third", exclusive=True)  # os.rename refuses on Windows
    monkeypatch.setattr(pub, "os", os)
    assert path.read_bytes() == b"first"
    assert not list(tmp_path.glob("*.writing-*"))


@pytest.mark.posix_only('the folder fsync is POSIX (Windows cannot fsync a directory handle)')
def test_a_journal_entry_is_written_aside_fsynced_then_renamed(tmp_path, monkeypatch):
    target = tmp_path / "trial-0001.npz"
    target.write_bytes(b"previous entry")
    seen_during_write = []

    def write(fh):
        seen_during_write.append(target.read_bytes())  # the entry is untouched meanwhile
        fh.write(b"new entry")
    calls = _spy(monkeypatch, journal.os)
    with os_platform.forced("posix"):
        journal.write_durable(target, write)
    assert seen_during_write == [b"previous entry"]
    assert calls == [("fsync", "file"), ("replace", "trial-0001.npz"), ("fsync", "dir")]
    assert target.read_bytes() == b"new entry" and not list(tmp_path.glob("*.tmp"))


def test_a_failed_journal_write_leaves_the_entry_and_no_temp_file(tmp_path):
    target = tmp_path / "trial-0001.npz"
    target.write_bytes(b"previous entry")

    def write(fh):
        fh.write(b"half")
        raise OSError(28, "No space left on device")
    with pytest.raises(journal.DiskFullError):
        journal.write_durable(target, write)
    assert target.read_bytes() == b"previous entry" and not list(tmp_path.glob("*.tmp"))


def test_the_compact_journal_entry_round_trips_bit_for_bit(tmp_path):
    rng = np.random.default_rng(5)
    n = 700
    lsb = 20.0 / 65536
    t = Trial(sE=0.5, repeat=2, fs_Hz=2000.0, rE=rng.random(n), I_ext_mA=rng.random(n),
              I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
              wrench=np.rint(rng.normal(scale=300, size=(n, 6))) * lsb,
              sync=(rng.random(n) > 0.5) * 5.0, extra_attrs={"schedule_index": 4})
    p = tmp_path / "trial-0001.npz"
    journal.save_trial_npz(p, t)
    u = journal.load_trial_npz(p)
    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync"):
        assert getattr(u, k).tobytes() == getattr(t, k).tobytes(), k
    assert u.extra_attrs == {"schedule_index": 4} and u.repeat == 2
    raw = 8 * n * 11
    assert p.stat().st_size < 0.8 * raw  # counts + shuffle + deflate: smaller than float64


def test_free_space_comes_from_shutil_disk_usage_not_statvfs(tmp_path, monkeypatch):
    monkeypatch.delattr(os, "statvfs", raising=False)
    import shutil
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10, 3, 7))
    assert pub.free_bytes(tmp_path) == 7


def test_o_binary_is_asked_for_at_each_open(tmp_path, monkeypatch):
    flags = []
    real_open = os.open
    monkeypatch.setattr(os, "O_BINARY", 0x8000, raising=False)

    def spy_open(p, fl, *a):
        flags.append(fl)
        return real_open(p, fl & ~0x8000, *a)
    monkeypatch.setattr(pub.os, "open", spy_open)
    with os_platform.forced("posix"):
        pub.publish_image(tmp_path / "b.h5", b"\n\n")
    assert flags and flags[0] & 0x8000
