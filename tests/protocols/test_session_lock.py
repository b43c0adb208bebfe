"""The single-writer lock on both systems: POSIX flock, and Windows' mandatory byte-range
locks (msvcrt.locking, run here against nmsid.testing.fake_windows_api)."""

from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from nmsid.protocols import session_lock
from nmsid.protocols.errors import SessionLockedError
from nmsid.protocols.session_lock import SessionLock, live_writer, lock_path
from nmsid.testing.platforms import WINE_LOCKING
from nmsid.testing.windows_emulation import emulate_windows

_HOLDER = """
import sys, time
path, platform, argv = sys.argv[1], sys.argv[2], sys.argv[3:]
sys.argv = argv  # the nmsid command line the holder pretends to run
from nmsid.protocols.session_lock import SessionLock
if platform == "windows":
    from nmsid.testing.windows_emulation import WindowsEmulation
    WindowsEmulation().install()
lock = SessionLock.acquire(path, "nmsid run")
print("held", flush=True)
sys.stdin.read()
lock.release()
print("released", flush=True)
"""


def _holder(path: Path, platform: str, argv: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path), platform, *argv],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


@pytest.mark.parametrize("platform", [
    pytest.param("posix", marks=pytest.mark.posix_only(
        "the POSIX lock: under the emulation this process follows Windows")),
    pytest.param("windows", marks=pytest.mark.wine_gap(WINE_LOCKING))])
@pytest.mark.parametrize("argv, kind", [(["nmsid", "gui", "--backend", "sim"], "nmsid gui"),
                                        (["nmsid", "run", "--backend", "sim"], "nmsid run")])
def test_a_second_writer_is_refused_naming_pid_host_start_and_kind(tmp_path, platform, argv,
                                                                    kind):
    path = tmp_path / "P01.h5"
    proc = _holder(path, platform, argv)
    try:
        ctx = emulate_windows() if platform == "windows" else _nothing()
        with ctx:
            with pytest.raises(SessionLockedError) as err:
                SessionLock.acquire(path, "nmsid run")
            writer = live_writer(path)
        message = str(err.value)
        assert f"process {proc.pid} on host {socket.gethostname()}" in message
        assert f", {kind})" in message and "(started 20" in message
        assert writer is not None and writer.pid == proc.pid and writer.command == kind
    finally:
        out, _ = proc.communicate("")
    assert out.strip() == "released"
    with emulate_windows() if platform == "windows" else _nothing():
        assert live_writer(path) is None
        SessionLock.acquire(path, "nmsid recover").release()
    assert not lock_path(path).exists()


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


@pytest.mark.wine_gap(WINE_LOCKING)
def test_windows_lock_leaves_the_writer_information_readable(tmp_path):
    """Windows' locks are mandatory: the locked byte lies beyond the information (on Linux
    against the fake's locks, on the Windows interpreter against Windows')."""
    path = tmp_path / "P01.h5"
    with emulate_windows() as emu:
        lock = SessionLock.acquire(path, "nmsid run")
        fd = os.open(lock_path(path), os.O_RDONLY | os.O_BINARY)
        try:
            if not emu.real:
                assert emu.msvcrt.conflicts(fd, session_lock.LOCK_OFFSET, 1)
                assert not emu.msvcrt.conflicts(fd, 0, session_lock.INFO_BYTES)
            with pytest.raises(PermissionError):  # ERROR_LOCK_VIOLATION: mandatory
                os.lseek(fd, session_lock.LOCK_OFFSET, os.SEEK_SET)
                os.read(fd, 1)
            assert session_lock._read_info(fd).pid == os.getpid()
        finally:
            os.close(fd)
        lock.release()


def test_windows_release_removes_the_lock_file_only_after_closing_it(tmp_path):
    """An open file cannot be deleted on Windows: close first, then unlink; a lock file
    another process holds open stays, unheld (no writer)."""
    path = tmp_path / "P01.h5"
    with emulate_windows():
        SessionLock.acquire(path, "nmsid run").release()
        assert not lock_path(path).exists()
        lock = SessionLock.acquire(path, "nmsid run")
        reader = open(lock_path(path), "rb")  # noqa: SIM115  (a probing reader, held)
        try:
            lock.release()
            assert lock_path(path).exists()
        finally:
            reader.close()
        assert live_writer(path) is None
        SessionLock.acquire(path, "nmsid run").release()
        assert not lock_path(path).exists()


def test_the_lock_module_needs_no_posix_module_on_windows(tmp_path):
    with emulate_windows():  # fcntl cannot be imported, os.pread / os.pwrite are gone
        lock = SessionLock.acquire(tmp_path / "P01.h5", "nmsid run")
        assert live_writer(tmp_path / "P01.h5").pid == os.getpid()
        lock.release()


def test_writer_kind_names_the_gui_and_recover(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["nmsid", "gui", "--backend", "sim"])
    assert session_lock.writer_kind("nmsid run") == "nmsid gui"
    assert session_lock.writer_kind("nmsid recover") == "nmsid recover"
    monkeypatch.setattr(sys, "argv", ["nmsid", "run", "--resume", "x.h5"])
    assert session_lock.writer_kind("nmsid run --resume") == "nmsid run --resume"


class _RefusingMsvcrt:
    """``msvcrt`` whose ``locking`` fails with one errno, as the CRT's ``_locking`` does."""

    LK_UNLCK, LK_LOCK, LK_NBLCK, LK_RLCK, LK_NBRLCK = 0, 1, 2, 3, 4

    def __init__(self, err: int):
        self.err = err

    def locking(self, fd, mode, nbytes):
        raise OSError(self.err, os.strerror(self.err))


@pytest.mark.parametrize("err", [errno.EACCES, errno.EDEADLOCK])
def test_a_windows_locking_violation_in_any_oserror_form_refuses_the_writer(tmp_path, err):
    """msvcrt.locking "Raises OSError on failure": EACCES (already locked) or EDEADLOCK
    (the CRT's retries ran out) both mean another writer, not a crash."""
    from nmsid.protocols import os_platform

    with os_platform.forced("windows"), \
            os_platform.fake_windows_api(msvcrt=_RefusingMsvcrt(err)):
        with pytest.raises(SessionLockedError):
            SessionLock.acquire(tmp_path / "P01.h5", "nmsid run")


def test_a_windows_locking_error_that_is_not_a_violation_is_not_called_a_writer(tmp_path):
    """EBADF / EINVAL from msvcrt.locking are faults of the caller: raised as they are."""
    from nmsid.protocols import os_platform

    with os_platform.forced("windows"), \
            os_platform.fake_windows_api(msvcrt=_RefusingMsvcrt(errno.EBADF)):
        with pytest.raises(OSError) as err:
            SessionLock.acquire(tmp_path / "P01.h5", "nmsid run")
    assert not isinstance(err.value, SessionLockedError) and err.value.errno == errno.EBADF
