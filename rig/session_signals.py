"""Signals and console events that end a session the way the E-stop does.

A closed terminal (SIGHUP), a service manager or ``kill`` (SIGTERM) and Ctrl+C (SIGINT)
must never leave the stimulator playing a downloaded trial unwatched. While a session runs,
:class:`SessionSignals` turns each of them into the same sequence as the E-stop button:

1. output to zero and the interlock latched, in the signal handler (the main thread), by
   the ``on_signal`` callback (``engine.commands.estop(...)`` then ``engine.commands.abort()``);
2. the trial in progress aborted with the reason ``"<SIGNAME> received"`` (the latch's
   reason) and the session closed with its ``session_end`` record by the engine thread;
3. the command exits with :func:`exit_code` = 128 + the signal number (the shell's
   convention: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP) and one line on stderr.

Python runs a signal handler in the main thread between bytecodes, so the main thread must
not block in C code for long: ``nmsid run`` joins its engine thread in 0.1 s slices and
``nmsid gui`` keeps a short Qt timer running so the interpreter gets control.

Windows (chosen by :func:`nmsid.protocols.os_platform.is_windows`)
-----------------------------------------------------------------
There is no SIGHUP, and SIGTERM is never delivered from outside. Ctrl+C, Ctrl+Break,
closing the console window, logoff and shutdown arrive as console control events, handed
to the routines registered with ``SetConsoleCtrlHandler`` (kernel32, through ``ctypes``) on
a thread the system creates for them, last-registered first. For CTRL_CLOSE_EVENT,
CTRL_LOGOFF_EVENT and CTRL_SHUTDOWN_EVENT the system ends the process as soon as the
routine returns, or after a time-out (5 s for a close event)
(learn.microsoft.com/windows/console/handlerroutine, .../setconsolectrlhandler).
:class:`SessionSignals` registers one routine that, for each of the five events:

1. zeroes the output at once on the routine's thread through ``stop_output(reason)`` when
   the caller gives one (``nmsid run``: ``engine.commands.estop``, which is thread-safe), then hands
   the event to the main thread (``_thread.interrupt_main``), where the same ``on_signal``
   callback as for a POSIX signal zeroes the output (again, idempotent) and ends the
   session, with the reason ``"CTRL_CLOSE_EVENT received (console window closed)"`` etc.
   Without ``stop_output`` (the GUI) the output waits for the main thread's next turn;
2. returns TRUE at once for Ctrl+C / Ctrl+Break (the command then ends as above: exit
   status 130 / 149, one line); for close, logoff and shutdown it first waits, at most
   :data:`TERMINATING_WAIT_S`, until the session is closed (the ``with`` block is left),
   so the file is complete before the system ends the process.

Not covered: ``taskkill /F`` and Task Manager's "End task" (TerminateProcess cannot be
handled); logoff and shutdown of a process that loaded user32.dll (``nmsid gui``: Windows
sends those to its windows, not to the console routine; the close of its console is
covered). The STG's own trial then runs to its end unwatched, as after a power cut of the
PC.
"""

from __future__ import annotations

import _thread
import ctypes
import logging
import signal
import threading
from collections.abc import Callable
from typing import Any, Self

from nmsid.protocols import os_platform

log = logging.getLogger(__name__)

#: The signals that end a session (SIGHUP does not exist on Windows).
SESSION_SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in
                                    ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)

#: How long a close / logoff / shutdown routine waits for the session to close before it
#: returns (and the system ends the process): below the 5 s the system allows a close.
TERMINATING_WAIT_S = 4.5


class ConsoleEvent(int):
    """A Windows console control event, as the number of the POSIX signal it stands for
    (the exit status is 128 + that number), with its own name and reason.

    Examples
    --------
    >>> ev = CONSOLE_EVENTS[2]
    >>> ev.name, int(ev), exit_code(ev)
    ('CTRL_CLOSE_EVENT', 1, 129)
    """

    name: str
    event: int
    why: str

    def __new__(cls, signum: int, name: str, event: int, why: str) -> Self:
        obj = super().__new__(cls, signum)
        obj.name, obj.event, obj.why = name, event, why
        return obj

    @property
    def terminating(self) -> bool:
        """The system ends the process once the routine returns (close, logoff, shutdown)."""
        return self.event in (2, 5, 6)


#: wincon.h's event numbers -> the event; SIGBREAK (21) is Windows' Ctrl+Break signal.
CONSOLE_EVENTS = {e.event: e for e in (
    ConsoleEvent(2, "CTRL_C_EVENT", 0, "Ctrl+C, operator E-stop"),
    ConsoleEvent(21, "CTRL_BREAK_EVENT", 1, "Ctrl+Break, operator E-stop"),
    ConsoleEvent(1, "CTRL_CLOSE_EVENT", 2, "console window closed"),
    ConsoleEvent(1, "CTRL_LOGOFF_EVENT", 5, "user logging off"),
    ConsoleEvent(1, "CTRL_SHUTDOWN_EVENT", 6, "system shutting down"))}


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for 15 (the name Python knows, else ``"signal N"``);
    ``"CTRL_CLOSE_EVENT"`` for a :class:`ConsoleEvent`."""
    if isinstance(signum, ConsoleEvent):
        return signum.name
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def signal_reason(signum: int) -> str:
    """The E-stop / abort reason a signal leaves in the session: ``"SIGTERM received"``;
    SIGINT adds that it is the operator's Ctrl+C."""
    if isinstance(signum, ConsoleEvent):
        return f"{signum.name} received ({signum.why})"
    extra = " (Ctrl+C, operator E-stop)" if signum == signal.SIGINT else ""
    return f"{signal_name(signum)} received{extra}"


def exit_code(signum: int) -> int:
    """Exit status of a command ended by ``signum``: 128 + the signal number."""
    return 128 + int(signum)


class SessionSignals:
    """Context manager: while active, SIGINT/SIGTERM/SIGHUP call ``on_signal(signum,
    reason)``; on exit the previous handlers are restored.

    Parameters
    ----------
    on_signal : callable(int, str)
        Called in the main thread with the signal number and :func:`signal_reason`. It
        must stop the output first (``engine.commands.estop(reason)``). Called again for a repeated
        signal (a second Ctrl+C): the E-stop is idempotent.
    stop_output : callable(str), optional
        Windows: called with the reason on the console routine's own thread, before the
        main thread runs ``on_signal``; it must be thread-safe (``engine.commands.estop``).

    Attributes
    ----------
    received : int or None
        The first signal received, if any.
    """

    def __init__(self, on_signal: Callable[[int, str], None],
                 stop_output: Callable[[str], None] | None = None):
        self.on_signal = on_signal
        self.stop_output = stop_output
        self.received: int | None = None
        self._old: dict[int, Any] = {}
        self._pending: list[ConsoleEvent] = []
        self._pending_lock = threading.Lock()
        self._closed = threading.Event()
        self._routine: Any = None
        self._kernel32: Any = None

    def _handler(self, signum, frame) -> None:
        with self._pending_lock:  # a console event handed over by its routine
            if self._pending:
                signum = self._pending.pop(0)
        if self.received is None:
            self.received = signum
        self.on_signal(signum, signal_reason(signum))

    # -- Windows console control events ----------------------------------------------
    def _console_routine(self, event: int) -> int:
        """The HandlerRoutine: runs on the thread the system creates for the event."""
        ev = CONSOLE_EVENTS.get(int(event))
        if ev is None:
            return 0  # not ours: the next routine (or the default) handles it
        if self.stop_output is not None:  # output to zero now, on this thread
            try:
                self.stop_output(signal_reason(ev))
            except Exception:  # the main thread's on_signal still follows
                log.exception("stop_output failed on the console event's thread")
        if self._old:  # the main thread runs on_signal, as for a POSIX signal
            with self._pending_lock:
                self._pending.append(ev)
            _thread.interrupt_main(signal.SIGINT)
        else:  # no handler could be installed (not the main thread): call it here
            if self.received is None:
                self.received = ev
            self.on_signal(ev, signal_reason(ev))
        if ev.terminating:  # the process ends when we return: let the session close
            self._closed.wait(TERMINATING_WAIT_S)
        return 1

    def _add_console_routine(self) -> None:
        kernel32 = os_platform.windows_api("kernel32")
        # BOOL WINAPI HandlerRoutine(DWORD dwCtrlType); WINFUNCTYPE exists on Windows only
        prototype = getattr(ctypes, "WINFUNCTYPE", ctypes.CFUNCTYPE)(ctypes.c_int,
                                                                     ctypes.c_uint)
        routine = prototype(self._console_routine)  # kept referenced while registered
        if not kernel32.SetConsoleCtrlHandler(routine, 1):
            log.warning("SetConsoleCtrlHandler failed: console close, logoff and shutdown "
                        "will not end the session like the E-stop")
            return
        self._kernel32, self._routine = kernel32, routine

    def __enter__(self) -> Self:
        self._closed.clear()
        for s in SESSION_SIGNALS:
            if not hasattr(signal, signal_name(s)):  # SIGHUP under a Windows emulation
                continue
            try:
                self._old[s] = signal.signal(s, self._handler)
            except ValueError:  # not the main thread: nothing can be installed
                log.warning("signal handlers can only be installed in the main thread")
                break
        if os_platform.is_windows():
            self._add_console_routine()
        return self

    def __exit__(self, *exc) -> None:
        self._closed.set()  # a close / logoff / shutdown routine may return now
        if self._routine is not None:
            self._kernel32.SetConsoleCtrlHandler(self._routine, 0)
            self._routine = self._kernel32 = None
        for s, old in self._old.items():
            signal.signal(s, old)
        self._old.clear()

    @property
    def exit_code(self) -> int | None:
        """128 + the first signal received, or None."""
        return None if self.received is None else exit_code(self.received)

    def stderr_line(self, path=None, *, complete: bool = False,
                    file_written: bool = True) -> str:
        """The one line a signalled command prints on stderr: what was saved and what to
        run next, only when something applies (issue 39).

        Parameters
        ----------
        path : path-like, optional
            The session file; None if no session was running.
        complete : bool
            Every planned trial completed (the signal came after the last one): no resume
            is offered, since a resume would have nothing to run.
        file_written : bool
            Whether the session file exists (a signal during the calibration leaves none:
            no trial was run, so nothing is named as closed).
        """
        head = f"nmsid: {signal_name(self.received or 0)} received: E-stop, output off"
        if path is None:
            return head + "; no session was running"
        if not file_written:
            return (f"{head}; stopped before the calibration was complete: no trial was "
                    f"run and no session file was written ({path}); start a new session "
                    f"with nmsid run")
        if complete:
            return (f"{head}; session complete and closed: {path} (every trial ran); "
                    f"identify it with nmsid identify {path} --out <folder>")
        return (f"{head}; session ended and closed: {path} (continue with nmsid run "
                f"--resume {path})")
