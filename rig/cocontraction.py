"""Co-contraction sessions: sE steps at a fixed rE, on the one engine.

A co-contraction sweep holds the balance of the two muscles (rE) fixed and steps their
sum (sE): each step is one ``cocontraction`` item of
:func:`nmsid.protocols.plan.cocontraction_plan`, held for ``step_s`` with the protocol's
rest between steps. It shows how the joint's static output and stiffness change with
co-activation at one balance (issue 41); the identification schedule's chirp trials are
not run.

The kind only prepares each item as a constant waveform (paper eqs. 1-4 at the step's sE
and the fixed rE, checked at the calibrated maxima as every trial's); the engine, its
preflight, the interlock, the journal and recovery are the same as for every session
(``docs/architecture.md``, "Adding a kind of session"). The sweep is recorded as
``session_kind = "cocontraction"`` and ``cocontraction_json``, so ``--resume`` rebuilds
the same plan (:meth:`CoContractionSession.from_stored`).

Examples
--------
>>> kind = CoContractionSession([0.3, 0.5, 0.7], rE=0.5, step_s=4.0)
>>> kind.root_attrs()["session_kind"], len(kind.plan(None))
('cocontraction', 3)
"""

from __future__ import annotations

import json
import math

import numpy as np

from nmsid.errors import UserError
from nmsid.protocols.plan import Plan, PlanItem, cocontraction_plan
from nmsid.protocols.schedule import PlannedTrial
from nmsid.protocols.waveforms import currents_mA
from nmsid.rig.trials import SessionKind, TrialNotRun, TrialRun

SESSION_KIND = "cocontraction"


class CoContractionSession(SessionKind):
    """sE steps at a fixed rE (:func:`~nmsid.protocols.plan.cocontraction_plan`).

    Parameters
    ----------
    sE_steps : sequence of float
        The co-activation of each step, in the order run, each in (0, 1].
    rE : float
        The fixed balance, in [0, 1] (0.5: equal normalised intensities).
    step_s : float
        How long each step is held, s.
    repeats : int
        How many times the whole sweep is run.
    source : str
        Where the values came from (named by refusals).
    """

    kind = SESSION_KIND

    def __init__(self, sE_steps, rE: float, step_s: float, *, repeats: int = 1,
                 source: str = ""):
        self.sE_steps = tuple(float(v) for v in sE_steps)
        self.rE, self.step_s, self.repeats = float(rE), float(step_s), int(repeats)
        self.source = source or "co-contraction sweep"
        if not self.sE_steps or self.repeats < 1:
            raise UserError(f"{self.source}: a co-contraction sweep needs at least one sE "
                            f"step and one repeat (got {len(self.sE_steps)} steps, "
                            f"{repeats!r} repeats)")
        self._plan = cocontraction_plan(self.sE_steps, self.rE, self.step_s,
                                        repeats=self.repeats, source=self.source)

    def plan(self, engine) -> Plan:
        return self._plan

    def root_attrs(self) -> dict:
        return {"session_kind": SESSION_KIND, "cocontraction_json": json.dumps(
            {"sE_steps": list(self.sE_steps), "rE": self.rE, "step_s": self.step_s,
             "repeats": self.repeats}, sort_keys=True)}

    @classmethod
    def from_stored(cls, attrs: dict, where: str) -> CoContractionSession:
        """The sweep a session recorded (``--resume``).

        Raises
        ------
        UserError
            If ``cocontraction_json`` is missing or not a sweep.
        """
        try:
            d = json.loads(attrs["cocontraction_json"])
            return cls(d["sE_steps"], d["rE"], d["step_s"], repeats=d.get("repeats", 1),
                       source=f"{where} (recorded co-contraction sweep)")
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"{where}: the recorded co-contraction sweep cannot be read "
                            f"({type(exc).__name__}: {exc})") from None

    def schedule(self, engine) -> list[PlannedTrial]:
        return [PlannedTrial(index=it.index, sE=it.sE, repeat=it.repeat) for it in self._plan]

    def resume_from(self, engine, trial_attrs: list[dict]) -> None:
        if len(engine.schedule) != len(self._plan):
            raise UserError(f"{engine.path}: {len(engine.schedule)} trials recorded in its "
                            f"schedule, {len(self._plan)} in the recorded sweep; it cannot "
                            "be resumed")

    def prepare(self, engine, item: PlanItem, planned: PlannedTrial) -> TrialRun:
        p, cal = engine.config.protocol, engine.calibration
        n = int(round(item.duration_s * p.fs_Hz))
        if n < 1 or not math.isfinite(item.duration_s):
            raise TrialNotRun(f"step of {item.duration_s!r} s has no sample")
        rE = np.full(n, item.rE_range[0])
        I_ext, I_flex = currents_mA(rE, item.sE, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA,
                                    cal.Ifmax_mA)
        try:
            checked = engine._checked(I_ext, I_flex, calibrated=True)
        except ValueError as exc:  # CurrentLimitError: never sent
            raise TrialNotRun(f"waveform refused: {exc}", trip=str(exc)) from None
        return TrialRun(n=checked.n_samples, sE=item.sE, rE=rE, I_ext_mA=checked.I_ext_mA,
                        I_flex_mA=checked.I_flex_mA, checked=checked, text=item.label,
                        attrs={"trial_kind": SESSION_KIND,
                               "cocontraction_rE": float(item.rE_range[0])})

    def __repr__(self) -> str:
        return (f"CoContractionSession({len(self.sE_steps)} sE steps at rE {self.rE:g}, "
                f"{self.step_s:g} s each, x{self.repeats})")
