"""One writer per session: a lock beside the session file, ``<file>.lock``.

The writer (``nmsid run``, ``nmsid gui``, ``run --resume``, ``recover``) holds an exclusive
lock on ``<file>.lock`` for as long as it writes the file or its journal. The system drops
the lock when the process ends in any way (exit, exception, kill, power loss), so a crash
can never leave a stale lock: a ``.lock`` file nobody holds means "no writer". The file's
first :data:`INFO_BYTES` bytes hold the writer's PID, host, start time and kind of command
(JSON, space-padded), so a refused second writer, and a reader (``nmsid validate``,
``identify``, ...), can name it.

Two implementations, chosen at call time by :func:`nmsid.protocols.os_platform.is_windows`:

- **POSIX**: ``flock(LOCK_EX | LOCK_NB)`` on the whole file (advisory: readers can still
  read the information). On release the file is unlinked while still locked, so nobody can
  be fooled by it.
- **Windows**: ``msvcrt.locking(fd, LK_NBLCK, 1)`` on the single byte at
  :data:`LOCK_OFFSET`, beyond the information. Windows byte-range locks are mandatory
  (LockFileEx: locks "prevent other processes from reading from or writing to the locked
  region"), so a lock over the information would hide it from the process it refuses; a
  region may lie beyond the end of the file (docs.python.org/3/library/msvcrt.html,
  ``locking``). A file held open cannot be deleted there (DeleteFileW), so on release the
  lock is given up and the handle closed first, then the file is removed if nobody else has
  it open (if someone does, it stays: an unheld lock file means "no writer").

Why not filelock or portalocker: filelock opens its lock file with ``O_TRUNC`` on every
attempt (the refused process would wipe the holder's name) and locks byte 0 on Windows;
portalocker locks from the current position, i.e. over the information. Both would need
the same byte-range care as the few lines here, which add no dependency.

Readers never take this lock for longer than a probe (a non-blocking lock, released at
once; a writer refused by a probe retries), and it is a separate file from the session
file: HDF5's own file locks and ordinary HDF5 tools never see it.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from nmsid.protocols import os_platform
from nmsid.protocols.errors import SessionLockedError
from nmsid.protocols.session_model import utc_now

LOCK_SUFFIX = ".lock"
_ACQUIRE_TRIES = 5
"""A probe holds LOCK_SH for microseconds: a refused LOCK_EX is retried a few times."""
_RETRY_S = 0.05
#: The writer information occupies bytes [0, INFO_BYTES) of the lock file.
INFO_BYTES = 4096
#: The byte locked on Windows: beyond the information, which stays readable.
LOCK_OFFSET = INFO_BYTES
#: What the CRT's ``_locking`` sets errno to when the region is locked by another handle:
#: EACCES "Locking violation (file already locked or unlocked)", EDEADLOCK "Locking
#: violation" after its retries (learn.microsoft.com/cpp/c-runtime-library/reference/locking).
_LOCKED_ERRNOS = frozenset({errno.EACCES, errno.EDEADLOCK})


def _binary() -> int:
    """``os.O_BINARY`` where it exists: bytes as written, not a text-mode descriptor."""
    return getattr(os, "O_BINARY", 0)


def lock_path(path: str | os.PathLike) -> Path:
    """``<file>.lock`` beside the session file."""
    p = Path(path)
    return p.with_name(p.name + LOCK_SUFFIX)


@dataclass
class WriterInfo:
    """Who holds a session's lock."""

    pid: int = 0
    host: str = ""
    started_utc: str = ""
    command: str = ""

    def describe(self) -> str:
        """``process 1234 on host lab-pc (nmsid run, started 2026-...Z)``."""
        if not self.pid:
            return "another process (it has not written its name yet)"
        what = f", {self.command}" if self.command else ""  # the kind of writer
        return (f"process {self.pid} on host {self.host or '?'} (started "
                f"{self.started_utc or '?'}{what})")


def _cli_subcommand() -> str:
    """The nmsid command this process runs (``gui`` for ``nmsid gui ...``), else ``""``."""
    words = [a for a in sys.argv[1:] if not a.startswith("-")]
    return words[0] if words else ""


def writer_kind(command: str) -> str:
    """The kind of writer to name to a refused process: ``nmsid run``, ``nmsid run
    --resume``, ``nmsid gui`` or ``nmsid recover``.

    ``command`` is what the caller says it does; a session started from the GUI says
    ``nmsid run`` but the process is ``nmsid gui``, and that is what the operator sees.
    """
    if "recover" in command:
        return "nmsid recover"
    if _cli_subcommand() == "gui":
        return "nmsid gui"
    return command


def _try_lock(fd: int) -> bool:
    """Take the writer lock on ``fd`` without waiting; False if another process has it."""
    if os_platform.is_windows():
        msvcrt = os_platform.windows_api("msvcrt")
        os.lseek(fd, LOCK_OFFSET, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError as exc:  # msvcrt.locking: "Raises OSError on failure"
            if exc.errno in _LOCKED_ERRNOS:
                return False
            raise  # EBADF, EINVAL: not another writer
        return True
    import fcntl  # POSIX only, behind the switch

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _probe(fd: int) -> bool:
    """True if a writer holds the lock (a reader's instantaneous probe)."""
    if os_platform.is_windows():
        if not _try_lock(fd):
            return True
        _unlock(fd)
        return False
    import fcntl  # POSIX only, behind the switch

    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    fcntl.flock(fd, fcntl.LOCK_UN)
    return False


def _unlock(fd: int) -> None:
    if os_platform.is_windows():
        msvcrt = os_platform.windows_api("msvcrt")
        os.lseek(fd, LOCK_OFFSET, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        return
    import fcntl  # POSIX only, behind the switch

    fcntl.flock(fd, fcntl.LOCK_UN)


def _write_info(fd: int, data: bytes) -> None:
    """The information at offset 0, padded to INFO_BYTES (no truncation, no pwrite)."""
    data = data[:INFO_BYTES].ljust(INFO_BYTES, b" ")
    os.lseek(fd, 0, os.SEEK_SET)
    while data:
        data = data[os.write(fd, data):]


def _read_info(fd: int) -> WriterInfo:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        raw = b""
        while len(raw) < INFO_BYTES:
            chunk = os.read(fd, INFO_BYTES - len(raw))
            if not chunk:
                break
            raw += chunk
        d = json.loads(raw.decode("utf-8", "replace").strip() or "{}")
        return WriterInfo(int(d.get("pid", 0)), str(d.get("host", "")),
                          str(d.get("started_utc", "")), str(d.get("command", "")))
    except (OSError, ValueError, TypeError, AttributeError):
        return WriterInfo()


_held: dict[str, list] = {}
"""Locks this process holds: resolved lock path -> [SessionLock, count] (re-entrant, so
``run --resume`` can call ``recover`` under its own lock)."""


class SessionLock:
    """The writer's lock on one session; use :meth:`acquire`, then :meth:`release`."""

    def __init__(self, path: Path, fd: int):
        self.path = path
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, session_path: str | os.PathLike, command: str = "") -> SessionLock:
        """Take the session's writer lock, or refuse naming the live writer.

        Raises
        ------
        SessionLockedError
            If another process holds it.
        """
        lp = lock_path(session_path)
        key = str(lp.resolve())
        if key in _held:
            _held[key][1] += 1
            return _held[key][0]
        lp.parent.mkdir(parents=True, exist_ok=True)
        command = writer_kind(command)
        for attempt in range(_ACQUIRE_TRIES * 4):
            fd = os.open(lp, os.O_RDWR | os.O_CREAT | _binary(), 0o644)
            if not _try_lock(fd):
                info = _read_info(fd)
                os.close(fd)
                if attempt + 1 >= _ACQUIRE_TRIES:
                    raise SessionLockedError(session_path, info.describe()) from None
                time.sleep(_RETRY_S)
                continue
            # the lock file may have been unlinked by a releasing writer meanwhile
            try:
                same = os.stat(lp).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            record = {"pid": os.getpid(), "host": socket.gethostname(),
                      "started_utc": utc_now(), "command": command}
            try:
                _write_info(fd, json.dumps(record).encode("utf-8"))
            except OSError as exc:  # a full disk: the lock holds, the name stays unknown
                if exc.errno not in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
                    raise
            lock = cls(lp, fd)
            _held[key] = [lock, 1]
            return lock
        raise SessionLockedError(session_path, "another process (the lock file keeps "
                                               "changing)")

    def release(self) -> None:
        """Give the lock up (the last release of a re-entrant hold removes the file)."""
        key = str(self.path.resolve())
        entry = _held.get(key)
        if entry is not None and entry[1] > 1:
            entry[1] -= 1
            return
        _held.pop(key, None)
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        if os_platform.is_windows():
            # an open file cannot be deleted there: unlock and close, then remove it
            # unless another process has it open (then it stays, unheld: "no writer")
            try:
                _unlock(fd)
            finally:
                os.close(fd)
            try:
                os.unlink(self.path)
            except OSError:
                pass
            return
        try:
            os.unlink(self.path)  # while still locked: nobody can be fooled by it
        except OSError:
            pass
        os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None


def live_writer(session_path: str | os.PathLike) -> WriterInfo | None:
    """The process writing this session now, or None (no lock file, or nobody holds it).

    The probe holds a shared lock for an instant only; it never delays the writer.
    """
    lp = lock_path(session_path)
    key = str(lp.resolve()) if lp.exists() else ""
    if key in _held:
        return WriterInfo(os.getpid(), socket.gethostname(), "", "this process")
    try:
        fd = os.open(lp, os.O_RDONLY | _binary())
    except OSError:
        return None
    try:
        return _read_info(fd) if _probe(fd) else None
    finally:
        os.close(fd)
