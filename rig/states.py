"""The engine's states and the explicit table of legal transitions.

Every transition is logged (``logging``) and handed to listeners (the engine writes it to
the session's events and tells its observer). A transition not in :data:`TRANSITIONS`
raises :class:`IllegalTransition`.
"""

from __future__ import annotations

import enum
import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)


class State(enum.Enum):
    IDLE = "idle"
    """Nothing started yet; output off."""
    CALIBRATING = "calibrating"
    """Running the current ramps (output on during each step)."""
    ARMED = "armed"
    """Calibrated, interlock clear, ready to start the next trial; output off."""
    STIMULATING = "stimulating"
    """A trial is running; output on."""
    RESTING = "resting"
    """Between trials; output off."""
    PAUSED = "paused"
    """Held by the operator; output off."""
    TRIPPED = "tripped"
    """The interlock tripped (fault or E-stop); output off and latched until re-armed."""
    FINISHED = "finished"
    """Schedule done or session aborted; output off. Terminal."""


S = State
#: Legal transitions: from-state -> the states it may go to.
TRANSITIONS: dict[State, frozenset[State]] = {
    S.IDLE: frozenset({S.CALIBRATING, S.ARMED, S.PAUSED, S.TRIPPED, S.FINISHED}),
    S.CALIBRATING: frozenset({S.ARMED, S.PAUSED, S.TRIPPED, S.FINISHED}),
    S.ARMED: frozenset({S.STIMULATING, S.PAUSED, S.TRIPPED, S.FINISHED}),
    S.STIMULATING: frozenset({S.RESTING, S.PAUSED, S.TRIPPED, S.FINISHED}),
    S.RESTING: frozenset({S.ARMED, S.PAUSED, S.TRIPPED, S.FINISHED}),
    S.PAUSED: frozenset({S.ARMED, S.CALIBRATING, S.TRIPPED, S.FINISHED}),
    S.TRIPPED: frozenset({S.ARMED, S.CALIBRATING, S.FINISHED}),
    S.FINISHED: frozenset(),
}
del S

#: States in which the stimulator may deliver current.
OUTPUT_STATES = frozenset({State.CALIBRATING, State.STIMULATING})


class IllegalTransition(RuntimeError):
    """A state change that the transition table does not allow."""

    def __init__(self, old: State, new: State, reason: str = ""):
        self.old, self.new = old, new
        allowed = ", ".join(sorted(s.value for s in TRANSITIONS[old])) or "none (terminal)"
        super().__init__(f"illegal transition {old.value} -> {new.value}"
                         + (f" ({reason})" if reason else "")
                         + f"; from {old.value} the engine may go to: {allowed}")


class StateMachine:
    """Holds the current state; thread-safe reads, transitions through :meth:`to`.

    Parameters
    ----------
    listener : callable(old, new, reason), optional
        Called after every transition (in the thread that made it).
    """

    def __init__(self, listener: Callable[[State, State, str], None] | None = None,
                 initial: State = State.IDLE):
        self._state = initial
        self._lock = threading.Lock()
        self._listeners = [listener] if listener else []

    @property
    def state(self) -> State:
        return self._state

    def to(self, new: State, reason: str = "") -> State:
        """Change state; a no-op if already there. Returns the old state.

        Raises
        ------
        IllegalTransition
        """
        with self._lock:
            old = self._state
            if new is old:
                return old
            if new not in TRANSITIONS[old]:
                raise IllegalTransition(old, new, reason)
            self._state = new
        log.info("state %s -> %s%s", old.value, new.value, f" ({reason})" if reason else "")
        for fn in self._listeners:
            fn(old, new, reason)
        return old
