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
from collections.abc import Iterable
from dataclasses import dataclass

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
    reference: bool = False
    """A reference trial (fixed sE spread through the session to track fatigue)."""

    def to_dict(self) -> dict:
        d = {"index": self.index, "sE": self.sE, "repeat": self.repeat}
        if self.reference:
            d["reference"] = True
        return d


def make_schedule(sE_levels: Iterable[float], repeats: int,
                  randomisation: Randomisation, seed: int, *,
                  reference_sE: float | None = None,
                  reference_every: int = 0) -> list[PlannedTrial]:
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
    reference_sE, reference_every : float or None, int
        Reference trials (off by default): one trial at ``reference_sE`` first, after every
        ``reference_every`` scheduled trials, and last, so the gain at one fixed sE is
        measured through the session (fatigue, :mod:`nmsid.analysis.fatigue`). Their repeat
        numbers continue those of their level (a new level starts at 1).

    Returns
    -------
    list of PlannedTrial
        ``len(sE_levels) * repeats`` entries (plus the reference trials), all pending,
        ``index`` = position.

    Examples
    --------
    >>> s = make_schedule([0.3, 0.5], 2, Randomisation.FULL, 3, reference_sE=0.5,
    ...                   reference_every=2)
    >>> [(t.sE, t.repeat, t.reference) for t in s][::3]
    [(0.5, 3, True), (0.5, 4, True), (0.5, 5, True)]
    >>> len(s)
    7
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
    refs = [False] * len(pairs)
    if reference_sE is not None:
        if not (0.0 < float(reference_sE) <= 1.0) or reference_every < 1:
            raise ScheduleError(f"reference trials need reference_sE in (0, 1] and "
                                f"reference_every >= 1, got {reference_sE!r}, "
                                f"{reference_every!r}")
        ref = float(reference_sE)
        n_ref = max((r for s, r in pairs if abs(s - ref) < 1e-9), default=0)
        out, flags = [], []
        for k, pair in enumerate(pairs):
            if k % reference_every == 0:
                n_ref += 1
                out.append((ref, n_ref))
                flags.append(True)
            out.append(pair)
            flags.append(False)
        out.append((ref, n_ref + 1))
        flags.append(True)
        pairs, refs = out, flags
    return [PlannedTrial(index=i, sE=sE, repeat=r, reference=f)
            for i, ((sE, r), f) in enumerate(zip(pairs, refs, strict=True))]


def schedule_to_json(schedule: list[PlannedTrial]) -> str:
    """The planned order as JSON (stored in the session file as ``schedule_json``)."""
    return json.dumps([t.to_dict() for t in schedule])


def schedule_from_json(text: str) -> list[PlannedTrial]:
    """Inverse of :func:`schedule_to_json` (statuses all pending)."""
    try:
        items = json.loads(text)
        return [PlannedTrial(index=int(d["index"]), sE=float(d["sE"]), repeat=int(d["repeat"]),
                             reference=bool(d.get("reference", False)))
                for d in items]
    except (ValueError, KeyError, TypeError) as exc:
        raise ScheduleError(f"stored schedule is not readable: {exc}") from None
