"""Kinds of session: what the one engine needs to know to run a plan's items.

The engine (:mod:`nmsid.rig.engine`) has one trial path: it asks the session's kind to
*prepare* an item (a :class:`TrialRun`: a checked waveform, or a stream hook of
:func:`nmsid.rig.stimulation.run_block`, with the arrays it records), then runs the block,
writes the journal and the file, tells the observers and moves the state machine, the same
for every kind; after the trial the kind may add attributes and learn from it
(:meth:`SessionKind.after_trial`).

A kind (:class:`SessionKind`) is small: its plan (:mod:`nmsid.protocols.plan`), the root
attributes it records, how it prepares an item, and how it picks up again on ``--resume``.
:class:`IdentificationSession` is the paper's schedule; ``nmsid.rig.tracking.
TrackingSession`` is the force-tracking one. ``docs/architecture.md`` ("Adding a kind of
session") shows how to add one.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from nmsid.errors import UserError
from nmsid.protocols.plan import Plan, PlanItem, identification_plan
from nmsid.protocols.waveforms import input_attrs, trial_waveform

if TYPE_CHECKING:   # annotations only: the engine imports this module
    from nmsid.protocols.schedule import PlannedTrial
    from nmsid.rig.engine import Engine
    from nmsid.rig.stimulation import BlockResult


class TrialNotRun(Exception):
    """An item that cannot start (its reason is recorded; ``trip``: the interlock trips)."""

    def __init__(self, reason: str, *, trip: str = ""):
        super().__init__(reason)
        self.trip = trip


@dataclass
class TrialRun:
    """One prepared item, as the engine's trial path runs it.

    Exactly one of ``checked`` (a whole waveform, :func:`nmsid.rig.safety.check_waveform`)
    and ``stream`` (a closed-loop hook that fills ``rE`` / ``I_ext_mA`` / ``I_flex_mA`` as
    it commands) is set.
    """

    n: int
    sE: float
    rE: np.ndarray
    I_ext_mA: np.ndarray
    I_flex_mA: np.ndarray
    attrs: dict
    """The trial's optional attributes (the engine adds ``schedule_index`` and
    ``attempt``)."""
    text: str
    """What the trial is, for its events: its plan item's label (``sE 0.5 repeat 2``,
    ``twin tracking steps``)."""
    checked: Any = None
    stream: Any = None
    on_chunk: Callable[[int, int], None] | None = None
    """Called after each chunk [lo, hi) is journaled (extra observer callbacks)."""
    state: dict = field(default_factory=dict)
    """The kind's own objects for :meth:`SessionKind.after_trial` (a controller, ...)."""


class SessionKind:
    """What one kind of session adds to the engine (base: nothing special).

    Attributes
    ----------
    kind : str
        The plan's kind, recorded as ``session_kind`` unless ``identification``.
    reports_levels : bool
        The engine tells observers when all trials of one sE are done (identification).
    """

    kind = "identification"
    reports_levels = False

    def plan(self, engine: Engine) -> Plan:
        raise NotImplementedError

    def root_attrs(self) -> dict:
        """Root attributes a new session records (optional items of the contract)."""
        return {}

    def check_devices(self, devices) -> None:
        """Refuse devices this kind cannot run on (before anything stimulates)."""

    def schedule(self, engine: Engine) -> list[PlannedTrial] | None:
        """The schedule of a new session, or None for the configuration's."""
        return None

    def prepare(self, engine: Engine, item: PlanItem, planned: PlannedTrial) -> TrialRun:
        """The item ready to run.

        Raises
        ------
        TrialNotRun
            The item cannot run now (recorded as aborted, not started).
        """
        raise NotImplementedError

    def after_trial(self, engine: Engine, run: TrialRun, blk: BlockResult,
                    completed: bool) -> dict:
        """Attributes to add to the trial once it has run (before it is written)."""
        return {}

    def trial_written(self, engine: Engine, run: TrialRun, blk: BlockResult,
                      completed: bool) -> None:
        """The trial is in the journal and the file."""

    def resume_from(self, engine: Engine, trial_attrs: list[dict]) -> None:
        """Pick up again from the journal's trials' attributes (``--resume``)."""


class IdentificationSession(SessionKind):
    """The paper's randomised schedule of identification (and reference) trials."""

    kind = "identification"
    reports_levels = True

    def plan(self, engine: Engine) -> Plan:
        return identification_plan(engine.schedule, engine.config.protocol,
                                   source=str(engine.config.source or ""))

    def prepare(self, engine: Engine, item: PlanItem, planned: PlannedTrial) -> TrialRun:
        p = engine.config.protocol
        wf = trial_waveform(p, planned.sE, engine.calibration)
        try:
            checked = engine._checked(wf.I_ext_mA, wf.I_flex_mA, calibrated=True)
        except ValueError as exc:  # CurrentLimitError: never sent
            raise TrialNotRun(f"waveform refused: {exc}", trip=str(exc)) from None
        return TrialRun(n=checked.n_samples, sE=planned.sE, rE=wf.rE,
                        I_ext_mA=checked.I_ext_mA, I_flex_mA=checked.I_flex_mA,
                        attrs=dict(input_attrs(p)), checked=checked,
                        text=item.label)


SESSION_KINDS = {"tracking": ("nmsid.rig.tracking", "TrackingSession"),
                 "cocontraction": ("nmsid.rig.cocontraction", "CoContractionSession")}
"""The kinds of session besides identification, by their recorded ``session_kind``: the
module and class whose ``from_stored(attrs, where)`` rebuilds it on ``--resume``. A fixed
table of nmsid's own modules (a session file names a kind, never code), each imported only
when a session of its kind is resumed (the tracking kind loads the control design)."""


def session_kind_from_stored(attrs: dict, where: str) -> SessionKind | None:
    """The kind a session recorded (None: identification), rebuilt from its root
    attributes for ``--resume``.

    Raises
    ------
    UserError
        An unknown ``session_kind``, or recorded attributes its kind cannot read.
    """
    kind = attrs.get("session_kind")
    if kind in (None, "", "identification"):
        return None
    entry = SESSION_KINDS.get(str(kind))
    if entry is None:
        raise UserError(f"{where}: session_kind {kind!r} is not one this nmsid can resume "
                        f"(known: identification, {', '.join(SESSION_KINDS)})")
    module = importlib.import_module(entry[0])   # from the fixed table above only
    return getattr(module, entry[1]).from_stored(attrs, where)
