"""The operator's commands to one engine: :class:`OperatorCommands` (``engine.commands``).

The GUI, the headless run (``nmsid run``'s signal handling, :mod:`nmsid.api`) and the tests
command a running :class:`nmsid.rig.engine.Engine` through this one small object. Every
command is callable from any thread: the E-stop acts in the calling thread (output to
zero, latch); the others are queued and executed by the engine thread at its next check
(between chunks, during rests and waits; :meth:`nmsid.rig.engine.Engine` drains the queue
with :meth:`OperatorCommands.take`). A trip seen by the interlock's watcher thread is
queued the same way (:meth:`OperatorCommands.tripped`), so its event is written by the
engine thread.
"""

from __future__ import annotations

import enum
import queue
import threading
from collections.abc import Callable, Iterator
from typing import Any

from nmsid.protocols.session_file import Calibration

#: Longest engine wait between command checks, in real seconds (waits for the operator).
WAIT_SLICE_S = 0.02


class Cmd(enum.Enum):
    """A queued command (or a trip handed over by another thread)."""

    PAUSE = "pause"
    RESUME = "resume"
    ABORT = "abort"
    SKIP = "skip"
    RERUN = "rerun"
    REPEAT = "repeat"
    REARM = "rearm"
    CONFIRM = "confirm"
    NOTE = "note"
    TRIPPED = "tripped"


class OperatorCommands:
    """Thread-safe commands to one engine.

    Parameters
    ----------
    estop : callable(reason)
        Output to zero now and latch (the engine's interlock ``estop``), run in the
        calling thread.
    """

    def __init__(self, estop: Callable[[str], object]):
        self._estop = estop
        self._queue: queue.SimpleQueue[tuple[Cmd, Any]] = queue.SimpleQueue()
        self._wake = threading.Event()

    def __repr__(self) -> str:
        return f"OperatorCommands(queued={self._queue.qsize()})"

    # -- the operator's commands -------------------------------------------------------
    def estop(self, reason: str = "operator E-stop") -> None:
        """Output to zero now, in the calling thread, and latch the interlock."""
        self._estop(reason)
        self._wake.set()

    def rearm(self) -> None:
        """Clear the latch after a trip (refused, with an event, while the hardware
        switch is pressed); the session continues with the next pending trial."""
        self._put(Cmd.REARM)

    def pause(self) -> None:
        """Pause: the running trial finishes or is aborted (``protocol.pause_policy``),
        then output stays off until :meth:`resume`."""
        self._put(Cmd.PAUSE)

    def resume(self) -> None:
        """Leave ``paused`` (also: confirm after a device glitch, continue after a
        re-arm the GUI held)."""
        self._put(Cmd.RESUME)

    def abort(self, by: str = "operator") -> None:
        """End the session: the running trial is aborted, output off, file closed cleanly
        (it can be resumed later). ``by`` names who asked (the session's end record says
        ``aborted by <by>``), e.g. ``"SIGTERM received"`` for a signal."""
        self._put(Cmd.ABORT, str(by))

    def skip_trial(self) -> None:
        """Abort the running trial ("skipped by operator"), or between trials mark the
        next pending one aborted without running it."""
        self._put(Cmd.SKIP)

    def rerun(self, schedule_index: int) -> None:
        """Put an aborted trial back to pending; it runs next (refused, with an event,
        for a trial that is not aborted)."""
        self._put(Cmd.RERUN, int(schedule_index))

    def repeat_trial(self, schedule_index: int, reason: str) -> None:
        """Run a completed trial once more (e.g. the quality control excluded it while the
        participant is still there); it runs next. The recorded trial stays in the file
        and the new attempt is written as a new trial. Refused (event ``repeat_refused``)
        for a trial that is not completed."""
        self._put(Cmd.REPEAT, (int(schedule_index), str(reason)))

    def confirm_calibration(self, calibration: Calibration) -> None:
        """The operator's calibration (the measured one, or edited values); used when
        ``calibration.confirm`` is set. Refused (event ``calibration_refused``) if it
        breaks the contract or a current ceiling; the engine then keeps waiting."""
        self._put(Cmd.CONFIRM, calibration)

    def add_note(self, text: str) -> None:
        """An operator note, written to the session's events (kind ``note``)."""
        self._put(Cmd.NOTE, str(text))

    # -- the engine's side -------------------------------------------------------------
    def tripped(self, trip) -> None:
        """The interlock tripped (any thread): the engine thread logs it."""
        self._put(Cmd.TRIPPED, trip)

    def take(self) -> Iterator[tuple[Cmd, Any]]:
        """The queued commands, oldest first, until the queue is empty (engine thread)."""
        while True:
            try:
                yield self._queue.get_nowait()
            except queue.Empty:
                return

    def wait(self, timeout_s: float = WAIT_SLICE_S) -> None:
        """Sleep (real time) until a command arrives or ``timeout_s`` passes."""
        self._wake.wait(timeout_s)
        self._wake.clear()

    def _put(self, cmd: Cmd, arg=None) -> None:
        self._queue.put((cmd, arg))
        self._wake.set()
