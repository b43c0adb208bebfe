"""Signals that end a session the way the E-stop does (SIGINT, SIGTERM, SIGHUP).

A closed terminal (SIGHUP), a service manager or ``kill`` (SIGTERM) and Ctrl+C (SIGINT)
must never leave the stimulator playing a downloaded trial unwatched. While a session runs,
:class:`SessionSignals` turns each of them into the same sequence as the E-stop button:

1. output to zero and the interlock latched, in the signal handler (the main thread), by
   the ``on_signal`` callback (``engine.estop(...)`` then ``engine.abort()``);
2. the trial in progress aborted with the reason ``"<SIGNAME> received"`` (the latch's
   reason) and the session closed with its ``session_end`` record by the engine thread;
3. the command exits with :func:`exit_code` = 128 + the signal number (the shell's
   convention: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP) and one line on stderr.

Python runs a signal handler in the main thread between bytecodes, so the main thread must
not block in C code for long: ``nmsid run`` joins its engine thread in 0.1 s slices and
``nmsid gui`` keeps a short Qt timer running so the interpreter gets control.
"""

from __future__ import annotations

import logging
import signal
from typing import Callable

log = logging.getLogger(__name__)

#: The signals that end a session (SIGHUP does not exist on Windows).
SESSION_SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in
                                    ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for 15 (the name Python knows, else ``"signal N"``)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def signal_reason(signum: int) -> str:
    """The E-stop / abort reason a signal leaves in the session: ``"SIGTERM received"``;
    SIGINT adds that it is the operator's Ctrl+C."""
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
        must stop the output first (``engine.estop(reason)``). Called again for a repeated
        signal (a second Ctrl+C): the E-stop is idempotent.

    Attributes
    ----------
    received : int or None
        The first signal received, if any.
    """

    def __init__(self, on_signal: Callable[[int, str], None]):
        self.on_signal = on_signal
        self.received: int | None = None
        self._old: dict[int, object] = {}

    def _handler(self, signum, frame) -> None:
        if self.received is None:
            self.received = signum
        self.on_signal(signum, signal_reason(signum))

    def __enter__(self) -> "SessionSignals":
        for s in SESSION_SIGNALS:
            try:
                self._old[s] = signal.signal(s, self._handler)
            except ValueError:  # not the main thread: nothing can be installed
                log.warning("signal handlers can only be installed in the main thread")
                break
        return self

    def __exit__(self, *exc) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)
        self._old.clear()

    @property
    def exit_code(self) -> int | None:
        """128 + the first signal received, or None."""
        return None if self.received is None else exit_code(self.received)

    def stderr_line(self, path=None) -> str:
        """The one line a signalled command prints on stderr (``path``: the session file,
        None if no session was running)."""
        head = f"nmsid: {signal_name(self.received)} received: E-stop, output off"
        if path is None:
            return head + "; no session was running"
        return (f"{head}; session ended and closed: {path} (continue with nmsid run "
                f"--resume {path})")
