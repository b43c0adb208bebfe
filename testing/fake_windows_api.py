"""Fakes of the two Windows APIs nmsid calls, built from Microsoft's and Python's documents.

:class:`FakeMsvcrt` stands for Python's ``msvcrt`` module (byte-range locks) and
:class:`FakeKernel32` for ``kernel32.dll`` through ``ctypes`` (console control events,
``SetThreadExecutionState``). They are plugged in with
:func:`nmsid.protocols.os_platform.fake_windows_api` (the Windows emulation does it), so the
Windows code paths of ``protocols.session_lock`` and ``rig.session_signals`` run on Linux.

Behaviours and their sources
----------------------------
msvcrt.locking(fd, mode, nbytes)
    "Lock part of a file based on file descriptor fd from the C runtime. Raises OSError on
    failure. The locked region of the file extends from the current file position for
    nbytes bytes, and may continue beyond the end of the file." LK_NBLCK / LK_NBRLCK fail at
    once; LK_LOCK / LK_RLCK retry once a second, 10 times (docs.python.org/3/library/
    msvcrt.html; CRT ``_locking``: errno EACCES "locking violation", EDEADLOCK after 10
    tries; unlocking a region that is not locked fails). Locks belong to the handle: another
    handle, in this process or another, conflicts (Linux open-file-description locks,
    ``F_OFD_SETLK``, have the same owner). The system releases them when the handle is
    closed or the process ends (LockFileEx: "If a process terminates with a portion of a
    file locked or closes a file that has outstanding locks, the locks are unlocked by the
    operating system").
Mandatory locks
    LockFileEx: "Locks ... prevent other processes from reading from or writing to the
    locked region"; ReadFile / WriteFile fail with ERROR_LOCK_VIOLATION (33) on it. While a
    :class:`FakeMsvcrt` is installed with :meth:`FakeMsvcrt.enforce`, ``os.read`` /
    ``os.write`` over a region another handle locked raise ``PermissionError`` (winerror 33).
SetConsoleCtrlHandler(HandlerRoutine, Add)
    Handlers are called last-registered first until one returns TRUE; if none does, the
    default handler calls ExitProcess. "the system creates a new thread in the process to
    execute the handler function". For CTRL_CLOSE_EVENT, CTRL_LOGOFF_EVENT and
    CTRL_SHUTDOWN_EVENT the process is terminated when the handler returns, whatever it
    returns, or when the time-out passes first: 5 s for a close event (HandlerRoutine
    callback function, "Timeouts"; learn.microsoft.com/windows/console/handlerroutine and
    .../setconsolectrlhandler). Event numbers: CTRL_C_EVENT 0, CTRL_BREAK_EVENT 1,
    CTRL_CLOSE_EVENT 2, CTRL_LOGOFF_EVENT 5, CTRL_SHUTDOWN_EVENT 6 (wincon.h).
SetThreadExecutionState(esFlags)
    Returns the previous state, or NULL (0) on failure; ES_CONTINUOUS 0x80000000 keeps the
    state until the next call with ES_CONTINUOUS; ES_SYSTEM_REQUIRED 0x00000001 keeps the
    system from sleeping (learn.microsoft.com/windows/win32/api/winbase/
    nf-winbase-setthreadexecutionstate).
"""

from __future__ import annotations

import errno
import os
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

try:  # imported with the module, before an emulation hides it
    import fcntl as _fcntl
except ImportError:  # Windows: it has msvcrt's own locks (msvcrt_here)
    _fcntl = None  # type: ignore[assignment]

ERROR_LOCK_VIOLATION = 33

CTRL_C_EVENT = 0
CTRL_BREAK_EVENT = 1
CTRL_CLOSE_EVENT = 2
CTRL_LOGOFF_EVENT = 5
CTRL_SHUTDOWN_EVENT = 6
#: Events after whose handler the system ends the process.
TERMINATING_EVENTS = (CTRL_CLOSE_EVENT, CTRL_LOGOFF_EVENT, CTRL_SHUTDOWN_EVENT)
#: HandlerRoutine "Timeouts": a close event's handler has 5 s.
CLOSE_TIMEOUT_S = 5.0

ES_SYSTEM_REQUIRED = 0x00000001
ES_CONTINUOUS = 0x80000000


class FakeMsvcrt:
    """``msvcrt``'s byte-range locks over Linux open-file-description locks."""

    LK_UNLCK, LK_LOCK, LK_NBLCK, LK_RLCK, LK_NBRLCK = 0, 1, 2, 3, 4

    def __init__(self, retry_s: float = 1.0) -> None:
        if _fcntl is None:
            raise RuntimeError("FakeMsvcrt stands in for msvcrt on Linux; on Windows use "
                               "msvcrt itself (msvcrt_here())")
        self._fcntl = _fcntl
        self._retry_s = retry_s
        self._mine: set[tuple[int, int, int]] = set()
        self._lock = threading.Lock()
        self._saved: dict[str, Any] = {}

    def _flock(self, fd: int, cmd: int, kind: int, start: int, length: int) -> bytes:
        # struct flock: short l_type, short l_whence, off_t l_start, off_t l_len, pid_t
        # l_pid (0 for OFD locks), padded to 32 bytes on 64-bit Linux
        packed = struct.pack("hhqqi4x", kind, os.SEEK_SET, start, length, 0)
        return self._fcntl.fcntl(fd, cmd, packed)

    def locking(self, fd: int, mode: int, nbytes: int) -> None:
        """Lock or unlock ``nbytes`` bytes from ``fd``'s current position (see module)."""
        fcntl = self._fcntl
        start = os.lseek(fd, 0, os.SEEK_CUR)
        key = (fd, start, nbytes)
        if mode == self.LK_UNLCK:
            with self._lock:
                if key not in self._mine:
                    raise PermissionError(errno.EACCES, "locking violation: the region is "
                                                        "not locked")
                self._mine.discard(key)
            self._flock(fd, fcntl.F_OFD_SETLK, fcntl.F_UNLCK, start, nbytes)
            return
        tries = 10 if mode in (self.LK_LOCK, self.LK_RLCK) else 1
        # Windows locks a region through a read-only handle too; Linux needs a read lock
        # there (it still conflicts with any other handle's write lock)
        writable = os.O_RDONLY != fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE
        kind = fcntl.F_WRLCK if writable else fcntl.F_RDLCK
        for attempt in range(tries):
            try:
                self._flock(fd, fcntl.F_OFD_SETLK, kind, start, nbytes)
            except OSError as exc:
                if exc.errno not in (errno.EACCES, errno.EAGAIN):
                    raise
                if attempt + 1 < tries:
                    time.sleep(self._retry_s)
                continue
            with self._lock:
                self._mine.add(key)
            return
        if tries > 1:
            raise OSError(errno.EDEADLK, "resource deadlock would occur (10 tries)")
        raise PermissionError(errno.EACCES, "locking violation: the region is locked")

    def forget(self, fd: int) -> None:
        """Drop the bookkeeping of ``fd``'s locks (the system released them on close)."""
        with self._lock:
            self._mine = {k for k in self._mine if k[0] != fd}

    def conflicts(self, fd: int, start: int, length: int) -> bool:
        """True if another handle holds a lock overlapping ``[start, start + length)``."""
        fcntl = self._fcntl
        if length <= 0:
            return False
        got = self._flock(fd, fcntl.F_OFD_GETLK, fcntl.F_RDLCK, start, length)
        return struct.unpack("hhqqi4x", got)[0] != fcntl.F_UNLCK

    def enforce(self) -> FakeMsvcrt:
        """Make ``os.read`` / ``os.write`` / ``os.close`` follow mandatory locking."""
        if self._saved:
            return self
        real = {n: getattr(os, n) for n in ("read", "write", "close")}
        self._saved = real
        fake = self

        def position(fd: int) -> int | None:
            try:
                return os.lseek(fd, 0, os.SEEK_CUR)
            except OSError:  # a pipe or a terminal: no byte ranges
                return None

        def read(fd: int, n: int) -> bytes:
            pos = position(fd)
            if pos is not None and fake.conflicts(fd, pos, n):
                raise _lock_violation()
            return real["read"](fd, n)

        def write(fd: int, data: Any) -> int:
            pos = position(fd)
            if pos is not None and fake.conflicts(fd, pos, len(data)):
                raise _lock_violation()
            return real["write"](fd, data)

        def close(fd: int) -> None:
            fake.forget(fd)
            real["close"](fd)

        os.read, os.write, os.close = read, write, close  # type: ignore[assignment]
        return self

    def unenforce(self) -> None:
        """Undo :meth:`enforce`."""
        for name, fn in self._saved.items():
            setattr(os, name, fn)
        self._saved = {}


def msvcrt_here() -> Any:
    """The ``msvcrt`` for a test that plugs in Windows APIs: :class:`FakeMsvcrt` on Linux,
    Python's ``msvcrt`` itself on the Windows interpreter."""
    if _fcntl is None:
        import msvcrt  # noqa: PLC0415 (Windows only)

        return msvcrt
    return FakeMsvcrt()


def _lock_violation() -> PermissionError:
    exc = PermissionError(errno.EACCES, "[WinError 33] The process cannot access the file "
                                        "because another process has locked a portion of "
                                        "the file (emulated)")
    exc.winerror = ERROR_LOCK_VIOLATION  # type: ignore[attr-defined]
    return exc


class FakeKernel32:
    """The console-control and power functions of kernel32, with their documented timing.

    Parameters
    ----------
    terminate : callable(int) or None
        Called with the exit code when the system would end the process (after a
        terminating event's handler returns, or its time-out); default: record it only.
    close_timeout_s : float
        The time a close event's handler has before termination (5 s).
    """

    def __init__(self, terminate: Callable[[int], None] | None = None,
                 close_timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        self.handlers: list[Callable[[int], int]] = []
        self.terminate = terminate
        self.close_timeout_s = close_timeout_s
        self.terminated_with: int | None = None
        self.handler_threads: list[str] = []
        self.execution_state = 0
        self.execution_state_calls: list[tuple[int, int]] = []  # (flags, thread ident)
        self.execution_state_fails = False
        self._lock = threading.Lock()

    # -- console control -------------------------------------------------------------
    def SetConsoleCtrlHandler(self, handler: Any, add: int) -> int:
        """Add (``add`` true) or remove a handler routine; returns nonzero on success."""
        with self._lock:
            if add:
                self.handlers.append(handler)
                return 1
            for i in range(len(self.handlers) - 1, -1, -1):
                if self.handlers[i] is handler:
                    del self.handlers[i]
                    return 1
            return 0

    def deliver(self, event: int) -> threading.Thread:
        """Send a console control event: the handlers run on a new thread (returned)."""
        def run() -> None:
            with self._lock:
                handlers = list(reversed(self.handlers))
            self.handler_threads.append(threading.current_thread().name)
            done = threading.Event()
            handled = [False]

            def call_handlers() -> None:
                for h in handlers:
                    if h(event):
                        handled[0] = True
                        break
                done.set()

            if event in TERMINATING_EVENTS:
                worker = threading.Thread(target=call_handlers, daemon=True,
                                          name=f"console-handler-{event}")
                worker.start()
                done.wait(self.close_timeout_s)
                self._end(0xC000013A)  # STATUS_CONTROL_C_EXIT
                return
            call_handlers()
            if not handled[0]:
                self._end(0xC000013A)  # the default handler: ExitProcess

        t = threading.Thread(target=run, daemon=True, name=f"console-ctrl-event-{event}")
        t.start()
        return t

    def _end(self, code: int) -> None:
        self.terminated_with = code
        if self.terminate is not None:
            self.terminate(code)

    # -- power -----------------------------------------------------------------------
    def SetThreadExecutionState(self, flags: int) -> int:
        """Set the thread's execution state; returns the previous one."""
        flags = int(getattr(flags, "value", flags))  # a ctypes.c_uint, as a DWORD
        self.execution_state_calls.append((flags, threading.get_ident()))
        if self.execution_state_fails:
            return 0  # NULL: failure
        previous = self.execution_state or ES_CONTINUOUS
        if flags & ES_CONTINUOUS:
            self.execution_state = flags
        return previous
