"""What the engine tells the outside world: the observer interface, the run summary, and
the policy after a trip. (Re-exported by :mod:`nmsid.rig.engine`.)"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.protocols.reprs import html_repr, short_repr
from nmsid.protocols.schedule import PlannedTrial
from nmsid.protocols.session_file import Calibration, Event, Trial
from nmsid.rig.safety import Trip
from nmsid.rig.states import State


class TripPolicy(enum.Enum):
    """What the engine does after an interlock trip (output is already zero, latched)."""

    WAIT_FOR_REARM = "wait"
    """An operator is present (GUI): wait in ``tripped`` until the operator re-arms or
    aborts. Also, when the schedule has nothing pending left but some trials are aborted
    (tripped, skipped), wait in ``paused`` (reason :func:`rerun_wait_reason`) until the
    operator re-runs one or ends the session, instead of finishing by itself."""
    END_SESSION = "end"
    """End the run (headless: nobody is there to re-arm); resume later. Never waits."""


#: How the reason of the "schedule done, aborted trials left" wait (state ``paused``)
#: starts; also the start of ``RunSummary.ended_by`` when the operator ends that wait.
RERUN_WAIT_PREFIX = "schedule done"


def rerun_wait_reason(n_aborted: int) -> str:
    """The reason the engine gives with ``paused`` while it waits for a re-run.

    Parameters
    ----------
    n_aborted : int
        Aborted trials left in the schedule.
    """
    return (f"{RERUN_WAIT_PREFIX}; {n_aborted} aborted trial(s) can be re-run; re-run or "
            "end the session")


def is_rerun_wait(state: State | str, reason: str) -> bool:
    """True if ``(state, reason)`` from :meth:`EngineObserver.on_state` is the wait for a
    re-run after the schedule (as opposed to an operator's pause). ``state`` is a
    :class:`State` or its value (``"paused"``)."""
    return str(getattr(state, "value", state)) == State.PAUSED.value and \
        str(reason).startswith(RERUN_WAIT_PREFIX + ";")



class EngineObserver:
    """Receives the engine's progress; every method is a no-op here. Called from the
    engine thread: keep them quick (hand data to the GUI thread, do not draw here)."""

    def on_state(self, old: State, new: State, reason: str) -> None:
        """Every transition. ``paused`` is either the operator's pause or, with
        ``WAIT_FOR_REARM``, the wait for a re-run after the schedule: tell them apart with
        :func:`is_rerun_wait`."""

    def on_event(self, event: Event) -> None: ...

    def on_calibration_step(self, muscle: str, current_mA: float, force_N: float) -> None: ...

    def on_calibration_result(self, calibration: Calibration) -> None: ...

    def on_trial_started(self, index: int, planned: PlannedTrial) -> None: ...

    def on_chunk(self, index: int, start_index: int, force_N: np.ndarray, rE: np.ndarray,
                 I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None: ...

    def on_target(self, index: int, start_index: int, target_N: np.ndarray) -> None:
        """A tracking trial's target force for the samples of the chunk just reported by
        :meth:`on_chunk` (N, from ``start_index``); identification trials have none."""

    def on_trial_finished(self, index: int, trial: Trial) -> None: ...

    def on_level_completed(self, sE: float, trials: list[Trial]) -> None: ...

    def on_finished(self, path: str) -> None: ...


@dataclass
class RunSummary:
    """How a run ended."""

    path: Path
    final_state: State
    ended_by: str
    """``schedule complete``, ``aborted by operator``, ``interlock: <rule>: <detail>``,
    ``schedule done; ended by operator with N aborted trial(s) not re-run`` (the operator
    ended the wait for a re-run, ``WAIT_FOR_REARM`` only) or ``error: ...``."""
    n_completed: int
    n_aborted: int
    n_pending: int
    calibration: Calibration | None
    journal_removed: bool
    engine_time_s: float
    trip: Trip | None = None
    completed_names: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """Every planned trial completed."""
        return self.n_pending == 0 and self.n_aborted == 0

    def __repr__(self) -> str:
        return short_repr("RunSummary", str(self.path),
                          f"{self.n_completed} completed, {self.n_aborted} aborted, "
                          f"{self.n_pending} not run", self.ended_by,
                          f"state {getattr(self.final_state, 'name', self.final_state)}",
                          f"engine {self.engine_time_s:.3g} s")

    _repr_html_ = html_repr
