"""One writer per session: an advisory lock beside the session file, ``<file>.lock``.

The writer (``nmsid run``, ``run --resume``, ``recover``) holds ``flock(LOCK_EX)`` on
``<file>.lock`` for as long as it writes the file or its journal. The kernel drops the lock
when the process ends in any way (exit, exception, SIGKILL, power loss), so a crash can
never leave a stale lock: a ``.lock`` file nobody holds means "no writer". The file holds
the writer's PID, host, start time and command (JSON), so a refused second writer, and a
reader (``nmsid validate``, ``identify``, ...), can name it.

Readers never take this lock for longer than a probe (``LOCK_SH | LOCK_NB``, released at
once), and it is a separate file from the session file: HDF5's own file locks and
ordinary HDF5 tools never see it.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from nmsid.protocols.errors import SessionLockedError
from nmsid.protocols.session_model import utc_now

LOCK_SUFFIX = ".lock"
_ACQUIRE_TRIES = 5
"""A probe holds LOCK_SH for microseconds: a refused LOCK_EX is retried a few times."""
_RETRY_S = 0.05


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
        what = f", {self.command}" if self.command else ""
        return (f"process {self.pid} on host {self.host or '?'} (started "
                f"{self.started_utc or '?'}{what})")


def _read_info(fd: int) -> WriterInfo:
    try:
        raw = os.pread(fd, 4096, 0)
        d = json.loads(raw.decode("utf-8", "replace") or "{}")
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
        for attempt in range(_ACQUIRE_TRIES * 4):
            fd = os.open(lp, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
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
            info = {"pid": os.getpid(), "host": socket.gethostname(),
                    "started_utc": utc_now(), "command": command}
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, json.dumps(info).encode("utf-8"), 0)
            except OSError as exc:  # a full disk: the lock holds, the name stays unknown
                if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
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
        try:
            os.unlink(self.path)  # while still locked: nobody can be fooled by it
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

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
        fd = os.open(lp, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_info(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
