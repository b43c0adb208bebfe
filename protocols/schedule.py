"""The randomised trial schedule: which sE, which repeat, in which order (pure).

The order is drawn from a recorded seed with numpy's PCG64 generator, so the same seed,
levels, repeats and randomisation always give the same schedule.

Examples
--------
>>> s = make_schedule([0.3, 0.4], repeats=2, randomisation=Randomisation.BLOCKS, seed=1)
>>> [(t.sE, t.repeat) for t in s] in ([(0.3, 1), (0.3, 2), (0.4, 1), (0.4, 2)],
...                                    [(0.4, 1), (0.4, 2), (0.3, 1), (0.3, 2)])
True
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from nmsid.protocols.config import Randomisation
from nmsid.protocols.errors import ScheduleError


class TrialStatus(enum.Enum):
    """Where a planned trial stands."""

    PENDING = "pending"
    RUNNING = "running"
    DONE = "done"
    ABORTED = "aborted"


@dataclass
class PlannedTrial:
    """One entry of the schedule.

    ``index`` is the position in the planned order (0-based) and never changes; the
    engine updates ``status`` and ``reason`` as the session goes.
    """

    index: int
    sE: float
    repeat: int
    status: TrialStatus = TrialStatus.PENDING
    reason: str = ""
    """Why it was aborted (empty otherwise)."""
    attempts: int = 0
    """How many times it was started (re-runs count)."""

    def to_dict(self) -> dict:
        return {"index": self.index, "sE": self.sE, "repeat": self.repeat}


def make_schedule(sE_levels: Iterable[float], repeats: int,
                  randomisation: Randomisation, seed: int) -> list[PlannedTrial]:
    """Build the randomised schedule.

    Parameters
    ----------
    sE_levels : iterable of float
        The distinct sE levels.
    repeats : int
        Repetitions per level (>= 1).
    randomisation : Randomisation
        ``BLOCKS``: the order of the levels is random and the repeats of one level run
        together (repeat 1, 2, 3). ``FULL``: every trial is shuffled; repeats of a level
        are numbered in the order they run.
    seed : int
        The recorded random seed (>= 0).

    Returns
    -------
    list of PlannedTrial
        ``len(sE_levels) * repeats`` entries, all pending, ``index`` = position.
    """
    levels = [float(v) for v in sE_levels]
    if not levels:
        raise ScheduleError("no sE levels to schedule")
    if repeats < 1:
        raise ScheduleError(f"repeats must be >= 1, got {repeats}")
    if seed is None or seed < 0:
        raise ScheduleError(f"the schedule needs a recorded seed >= 0, got {seed!r}")
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    if randomisation is Randomisation.BLOCKS:
        order = rng.permutation(len(levels))
        pairs = [(levels[i], r + 1) for i in order for r in range(repeats)]
    elif randomisation is Randomisation.FULL:
        flat = [levels[i] for i in range(len(levels)) for _ in range(repeats)]
        perm = rng.permutation(len(flat))
        count: dict[float, int] = {}
        pairs = []
        for k in perm:
            sE = flat[k]
            count[sE] = count.get(sE, 0) + 1
            pairs.append((sE, count[sE]))
    else:
        raise ScheduleError(f"unknown randomisation {randomisation!r}; use one of "
                            + ", ".join(m.value for m in Randomisation))
    return [PlannedTrial(index=i, sE=sE, repeat=r) for i, (sE, r) in enumerate(pairs)]


def schedule_to_json(schedule: list[PlannedTrial]) -> str:
    """The planned order as JSON (stored in the session file as ``schedule_json``)."""
    return json.dumps([t.to_dict() for t in schedule])


def schedule_from_json(text: str) -> list[PlannedTrial]:
    """Inverse of :func:`schedule_to_json` (statuses all pending)."""
    try:
        items = json.loads(text)
        return [PlannedTrial(index=int(d["index"]), sE=float(d["sE"]), repeat=int(d["repeat"]))
                for d in items]
    except (ValueError, KeyError, TypeError) as exc:
        raise ScheduleError(f"stored schedule is not readable: {exc}") from None
