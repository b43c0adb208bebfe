"""Plans: every kind of session as a pure, finite, inspectable sequence of items.

A :class:`Plan` is data: the items a session will run, in order, each with its planned
output envelope (:class:`PlanItem`: kind, sE, the range of rE it may command, its
duration, the range of its force target). ``list(plan)`` works without hardware; the
command line, the GUI and the tests build the same plans (:func:`identification_plan`
here, ``nmsid.rig.tracking.tracking_plan`` for tracking sessions).

:func:`preflight` holds a plan to the session-file contract and the rig's limits before
anything stimulates, and again once the participant's calibration is known: every item's
most current per channel (paper eqs. 1-4 at the item's sE over its rE range) must stay at
or below that channel's calibrated maximum, the session's ceiling and the device's range.
A refusal is one line naming the plan's source (a file), the item, the value and what is
allowed (:class:`PlanRefused`).

Item kinds (:data:`ITEM_KINDS`): ``identification`` and ``reference`` trials (a waveform
at one sE), ``tracking`` and ``relay`` trials (closed loop: rE streamed by a controller,
clamped into the item's envelope by the engine), ``dry_run`` trials, ``cocontraction``
steps (one sE held at a fixed rE: :func:`cocontraction_plan`). A ``dry_run`` item
(:func:`dry_run_plan`: ``nmsid probe --dry-run`` into a dummy-load resistor, no
participant) carries its envelope as absolute currents (``max_mA``), held to the rig's
ceilings before anything connects, and to the dummy load's "calibration" after. Calibration is the
session's first step (its ramps are bounded by the rig's ceilings, checked here too); a
re-run is an item run again (its attempt counted by the engine), not a new item.

Examples
--------
>>> plan = Plan("identification", (PlanItem(0, "identification", 0.5, 15.0),
...                                PlanItem(1, "identification", 0.3, 15.0)))
>>> [it.sE for it in plan]
[0.5, 0.3]
>>> plan[0].max_current_mA(Calibration(2.0, 9.5, 1.5, 8.0))
(5.75, 4.75)
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

from nmsid.errors import UserError
from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS, Joint
from nmsid.protocols.session_model import Calibration

__all__ = ["DRY_RUN_LABELS", "DRY_RUN_ROLES", "ITEM_KINDS", "MAX_ITEM_S", "Plan", "PlanItem",
           "PlanRefused", "RigLimits", "cocontraction_plan", "dry_run_plan", "identification_plan",
           "preflight"]

ITEM_KINDS = ("identification", "reference", "tracking", "relay", "dry_run", "cocontraction")
"""The kinds of plan item."""

MAX_ITEM_S = 3600.0
"""The longest item a plan may hold (an hour of stimulation; the protocol's own bound on
one excitation). A target file with a time of 1e9 s is refused, not allocated."""

_TOL_MA = 1e-9


class PlanRefused(UserError):
    """A plan item outside the contract, the rig's limits or the calibration (one line)."""


@dataclass(frozen=True)
class PlanItem:
    """One item of a plan and its planned output envelope.

    Parameters
    ----------
    index : int
        Position in the plan (0-based, never changes).
    kind : str
        One of :data:`ITEM_KINDS`.
    sE : float
        Co-activation, in (0, 1] by the contract (``Imin + sE (Imax - Imin)`` never
        exceeds a channel's calibrated maximum).
    duration_s : float
        Output time, finite, in (0, :data:`MAX_ITEM_S`].
    repeat : int
        The repeat number recorded with the trial.
    rE_range : (float, float)
        The range of rE the item may command, inside [0, 1].
    target_range_N : (float, float) or None
        Lowest and highest force target (closed-loop items).
    label : str
        What the item is, for messages (``sE 0.5 repeat 2``, ``twin tracking steps``).
    controller : str
        Closed-loop items: ``relay``, ``twin``, ``baseline``.
    source : str
        The file the item comes from (a configuration, ``controller.json``, a target CSV),
        named by refusals.
    target_json : str
        Closed-loop items: the target's definition (recorded with the trial).
    max_mA : (float, float) or None
        The most current per channel (extensor, flexor) the item may command, in mA, when
        it is not given by sE and the rE range through a calibration (``dry_run`` items:
        a dummy load has none). Held to the rig's ceilings before anything is connected.
    """

    index: int
    kind: str
    sE: float
    duration_s: float
    repeat: int = 1
    rE_range: tuple[float, float] = (0.0, 1.0)
    target_range_N: tuple[float, float] | None = None
    label: str = ""
    controller: str = ""
    source: str = ""
    target_json: str = ""
    max_mA: tuple[float, float] | None = None

    def max_current_mA(self, calibration: Calibration) -> tuple[float, float]:
        """The most current per channel (extensor, flexor) this item may command with
        ``calibration``: paper eqs. 1-4 at its sE, extensor at the top of its rE range,
        flexor at the bottom; an item's own ``max_mA`` when it carries one."""
        if self.max_mA is not None:
            return (float(self.max_mA[0]), float(self.max_mA[1]))
        c = calibration
        lo, hi = self.rE_range
        return (c.Iemin_mA + hi * self.sE * (c.Iemax_mA - c.Iemin_mA),
                c.Ifmin_mA + (1.0 - lo) * self.sE * (c.Ifmax_mA - c.Ifmin_mA))

    def __repr__(self) -> str:
        return (f"PlanItem({self.index}, {self.kind}, sE {self.sE:g}, "
                f"{self.duration_s:g} s{', ' + self.label if self.label else ''})")


@dataclass(frozen=True)
class Plan:
    """A session's items in order (iterable, indexable, finite)."""

    kind: str
    """``identification``, ``tracking``, ... (the ``session_kind`` it records)."""
    items: tuple[PlanItem, ...] = field(default_factory=tuple)
    source: str = ""
    """The file the plan was built from (named by refusals)."""

    def __iter__(self) -> Iterator[PlanItem]:
        return iter(self.items)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, k: int) -> PlanItem:
        return self.items[k]

    @property
    def duration_s(self) -> float:
        """Output time of all items (rests not counted)."""
        return float(sum(it.duration_s for it in self.items))

    def __repr__(self) -> str:
        return f"Plan({self.kind}, {len(self.items)} items, {self.duration_s:g} s of output)"


@dataclass(frozen=True)
class RigLimits:
    """What a plan is held to besides the contract.

    Parameters
    ----------
    ceiling_ext_mA, ceiling_flex_mA : float
        The session's ceilings (``[calibration]``).
    force_limit_N : float
        The interlock's force limit: a target beyond it would trip it.
    device_max_mA : float or None
        The stimulator's range, once connected.
    joint : Joint
        The session's joint: ``force_limit_N`` and targets are in its unit (N m for a
        torque joint), refusals name its quantity, unit and channel roles.
    """

    ceiling_ext_mA: float
    ceiling_flex_mA: float
    force_limit_N: float
    device_max_mA: float | None = None
    joint: Joint = JOINTS[DEFAULT_JOINT]

    @classmethod
    def of(cls, config, device_max_mA: float | None = None) -> RigLimits:
        """The limits of a :class:`~nmsid.protocols.config.Config` (its joint's unit)."""
        c = config.calibration
        return cls(float(c.ceiling_ext_mA), float(c.ceiling_flex_mA),
                   float(config.interlock.force_limit_N),
                   None if device_max_mA is None else float(device_max_mA),
                   joint=config.joint_def)


def _finite(*xs) -> bool:
    try:
        return all(math.isfinite(float(x)) for x in xs)
    except (TypeError, ValueError):
        return False


def item_problem(item: PlanItem, limits: RigLimits,
                 calibration: Calibration | None = None) -> str | None:
    """What is wrong with one item (``"sE = 2 is outside (0, 1]"``), or None."""
    if item.kind not in ITEM_KINDS:
        return f"kind {item.kind!r} is unknown; valid: {', '.join(ITEM_KINDS)}"
    if not (_finite(item.sE) and 0.0 < item.sE <= 1.0):
        return (f"sE = {item.sE!r} is outside (0, 1] (sE = Ie + If; above 1 a channel "
                "would exceed its calibrated maximum)")
    lo, hi = item.rE_range
    if not (_finite(lo, hi) and 0.0 <= lo <= hi <= 1.0):
        return f"rE range [{lo!r}, {hi!r}] is not inside [0, 1]"
    if not (_finite(item.duration_s) and 0.0 < item.duration_s <= MAX_ITEM_S):
        return f"duration {item.duration_s!r} s is outside (0, {MAX_ITEM_S:g}] s"
    if item.target_range_N is not None:
        tlo, thi = item.target_range_N
        lim, q, u = limits.force_limit_N, limits.joint.quantity, limits.joint.unit
        if not (_finite(tlo, thi) and -lim <= tlo <= thi <= lim):
            return (f"{q} target range [{tlo!r}, {thi!r}] {u} is not finite within the "
                    f"interlock's {q} limit [-{lim:g}, {lim:g}] {u}")
    if item.max_mA is not None:   # absolute currents: the ceilings hold before calibration
        ce, cf = limits.ceiling_ext_mA, limits.ceiling_flex_mA
        if limits.device_max_mA is not None:
            ce, cf = min(ce, limits.device_max_mA), min(cf, limits.device_max_mA)
        for name, value, ceiling in ((limits.joint.extensor_role, item.max_mA[0], ce),
                                     (limits.joint.flexor_role, item.max_mA[1], cf)):
            if not (_finite(value) and 0.0 <= float(value) <= ceiling + _TOL_MA):
                return (f"{name} current up to {value!r} mA is outside [0, {ceiling:g}] mA "
                        "(the ceiling)")
    if calibration is not None:
        Ie, If = item.max_current_mA(calibration)
        ce, cf = limits.ceiling_ext_mA, limits.ceiling_flex_mA
        if limits.device_max_mA is not None:
            ce, cf = min(ce, limits.device_max_mA), min(cf, limits.device_max_mA)
        for name, value, cal_max, ceiling in (
                (limits.joint.extensor_role, Ie, calibration.Iemax_mA, ce),
                (limits.joint.flexor_role, If, calibration.Ifmax_mA, cf)):
            allowed = min(cal_max, ceiling)
            if not (_finite(value) and value <= allowed + _TOL_MA):
                return (f"{name} current up to {value:.4g} mA is above {allowed:g} mA (the "
                        f"calibrated maximum {cal_max:g} mA and the ceiling {ceiling:g} mA)")
    return None


def preflight(plan: Plan, limits: RigLimits, calibration: Calibration | None = None) -> None:
    """Hold every item of ``plan`` to the contract and the rig's limits (and, once known,
    the participant's calibration). Pure: nothing is touched.

    Raises
    ------
    PlanRefused
        One line: the plan's source, the first bad item, its value and what is allowed.
    """
    if len(plan) == 0:
        raise PlanRefused(f"{plan.source or plan.kind + ' plan'}: the plan has no items")
    for item in plan:
        problem = item_problem(item, limits, calibration)
        if problem is not None:
            where = item.source or plan.source or f"{plan.kind} plan"
            what = f"item {item.index}" + (f" ({item.label})" if item.label else "")
            raise PlanRefused(f"{where}: {what}: {problem}; nothing was stimulated"
                              if calibration is None else
                              f"{where}: {what}: {problem}; no trial was run")


def identification_plan(schedule, protocol, source: str = "") -> Plan:
    """The plan of an identification schedule (``PlannedTrial`` list) under ``protocol``
    (a ``ProtocolConfig``): each trial's rE range is the protocol's
    ``rE_centre +/- rE_amplitude``; reference trials are ``reference`` items."""
    lo = max(0.0, protocol.rE_centre - protocol.rE_amplitude)
    hi = min(1.0, protocol.rE_centre + protocol.rE_amplitude)
    items = tuple(
        PlanItem(pt.index, "reference" if pt.reference else "identification", float(pt.sE),
                 float(protocol.trial_s), repeat=int(pt.repeat), rE_range=(lo, hi),
                 label=f"sE {pt.sE:g} repeat {pt.repeat}")
        for pt in schedule)
    return Plan("identification", items, source=source)


def cocontraction_plan(sE_steps, rE: float, step_s: float, *, repeats: int = 1,
                       source: str = "") -> Plan:
    """A co-contraction sweep: each sE of ``sE_steps`` held for ``step_s`` at the fixed
    ``rE`` (both muscles on, their balance fixed, their sum stepped), in the given order,
    the whole sweep ``repeats`` times. Each step is one ``cocontraction`` item whose rE
    range is ``(rE, rE)``: the preflight holds its most current per channel to the
    calibration like any trial's. Nothing is checked here; :func:`preflight` refuses a bad
    value with its item.

    Examples
    --------
    >>> plan = cocontraction_plan([0.3, 0.6], 0.7, 5.0, repeats=2)
    >>> [(it.sE, it.repeat) for it in plan], plan[0].rE_range
    ([(0.3, 1), (0.6, 1), (0.3, 2), (0.6, 2)], (0.7, 0.7))
    >>> plan[1].max_current_mA(Calibration(2.0, 9.5, 1.5, 8.0))
    (5.15, 2.67)
    """
    steps = [float(v) for v in sE_steps]
    items = tuple(
        PlanItem(r * len(steps) + k, "cocontraction", sE, float(step_s), repeat=r + 1,
                 rE_range=(float(rE), float(rE)), label=f"sE {sE:g} at rE {float(rE):g}",
                 source=source)
        for r in range(int(repeats)) for k, sE in enumerate(steps))
    return Plan("cocontraction", items, source=source)


DRY_RUN_ROLES = ("download", "streamed", "estop")
"""The dry run's items: a downloaded trial checked on the resistor, a streamed
(tracking-style) trial, and the E-stop test (a chirp stopped by the E-stop mid-way; last,
as the E-stop ends the session)."""
DRY_RUN_LABELS = {"download": "dry run, downloaded trial",
                   "streamed": "dry run, streamed trial", "estop": "dry run, E-stop test"}
"""Each role's item label (what the operator reads; the kind finds an item's role by it)."""


def dry_run_plan(roles, channel: str, amplitude_mA: float, duration_s: float, *,
                 source: str = "") -> Plan:
    """The plan of ``nmsid probe --dry-run``: one ``dry_run`` item per role of ``roles``
    (:data:`DRY_RUN_ROLES`, in that order), each ``duration_s`` long with at most
    ``amplitude_mA`` on the tested ``channel`` (``extensor`` / ``flexor``) and nothing on
    the other (``max_mA``). Nothing is checked here; :func:`preflight` refuses a bad value
    with its item.

    Examples
    --------
    >>> plan = dry_run_plan(["download", "estop"], "flexor", 2.0, 1.0)
    >>> [(it.label, it.max_mA) for it in plan]
    [('dry run, downloaded trial', (0.0, 2.0)), ('dry run, E-stop test', (0.0, 2.0))]
    """
    order = [r for r in DRY_RUN_ROLES if r in roles]
    unknown = [r for r in roles if r not in DRY_RUN_ROLES]
    if unknown:
        raise PlanRefused(f"{source or 'dry run'}: role {unknown[0]!r} is unknown; valid: "
                          f"{', '.join(DRY_RUN_ROLES)}")
    a = float(amplitude_mA)
    env = (a, 0.0) if channel == "extensor" else (0.0, a)
    return Plan("dry_run", tuple(
        PlanItem(k, "dry_run", 1.0, float(duration_s), repeat=1, label=DRY_RUN_LABELS[r],
                 source=source, max_mA=env)
        for k, r in enumerate(order)), source=source)
