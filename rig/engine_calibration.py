"""Calibration as the engine runs it: manual, ramps, or the operator's confirmation.

A mixin of :class:`nmsid.rig.engine.Engine` (it uses the engine's state machine, interlock,
journal and command flags); the pure parts (ramp plans, threshold detection) live in
:mod:`nmsid.protocols.calibration`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nmsid.protocols.calibration import (
    Muscle,
    check_calibration,
    detect_thresholds,
    make_calibration,
    manual_calibration,
    ramp_currents_mA,
    require_thresholds,
    settled_mean_N,
    step_envelopes,
)
from nmsid.protocols.errors import CalibrationError
from nmsid.protocols.session_file import Calibration
from nmsid.rig.states import State

if TYPE_CHECKING:  # the engine this mixes into (nmsid.rig.engine imports this module)
    from nmsid.protocols.config import Config
    from nmsid.rig.session_log import SessionLog
    from nmsid.rig.states import StateMachine
    from nmsid.rig.stimulation import BlockResult


class CalibrationSteps:
    """The engine's calibration phase (mixin)."""

    # what it uses of the engine (set by :class:`nmsid.rig.engine.Engine`)
    config: Config
    calibration: Calibration | None
    _sm: StateMachine
    _confirmations: list[Calibration]
    _skip_req: bool

    if TYPE_CHECKING:
        @property
        def _open_log(self) -> SessionLog:
            raise NotImplementedError

        def _event(self, kind: str, detail: str = "") -> None:
            raise NotImplementedError

        def _notify(self, name: str, *args) -> None:
            raise NotImplementedError

        def _wait_operator(self, until, what: str) -> None:
            raise NotImplementedError

        def _check_interrupts(self, *, calibrating: bool = False) -> bool:
            raise NotImplementedError

        def _sleep_checking(self, duration_s: float) -> None:
            raise NotImplementedError

        def _stimulate(self, checked, *, n: int, on_samples=None,
                       watch_commands: bool = False, stream=None) -> BlockResult:
            raise NotImplementedError

        def _checked(self, I_ext_mA, I_flex_mA):
            raise NotImplementedError

    # -- calibration -------------------------------------------------------------------
    def _calibrate(self) -> None:
        c = self.config.calibration
        if self.calibration is not None:  # resumed session
            self._event("calibration", "from the session file (resume)")
            self._notify("on_calibration_result", self.calibration)
            return
        if c.manual is not None:
            cal = manual_calibration(c.manual, c)
            self._event("calibration", "entered by hand in the configuration")
        else:
            self._sm.to(State.CALIBRATING, "ramps")
            try:
                cal = self._ramps()
            except CalibrationError as exc:
                self._event("calibration_failed", str(exc))
                if not c.confirm:
                    raise
                cal = None
        if cal is not None:
            self._notify("on_calibration_result", cal)
        if c.confirm:
            self._confirmations.clear()
            while True:
                self._wait_operator(lambda: bool(self._confirmations), "confirm calibration")
                candidate = self._confirmations.pop(0)
                try:
                    check_calibration(candidate, c)
                except CalibrationError as exc:
                    self._event("calibration_refused", str(exc))
                    continue
                if cal is not None and not candidate.ramps:
                    candidate.ramps = dict(cal.ramps)  # keep the measured ramps
                cal = candidate
                break
            self._event("calibration_confirmed", _cal_text(cal))
        self._skip_req = False  # a skip pressed during calibration means nothing
        self.calibration = cal
        self._open_log.write_calibration(cal)
        self._event("calibration", _cal_text(cal))
        self._sm.to(State.ARMED, "calibrated")

    def _ramps(self) -> Calibration:
        c = self.config.calibration
        found, ramps = {}, {}
        for muscle in (Muscle.EXTENSOR, Muscle.FLEXOR):
            while True:
                try:
                    th, cur, frc, base = self._ramp(muscle)
                    break
                except _RedoRamp:
                    continue
            ramps[f"{muscle.prefix}_I_mA"] = np.asarray(cur)
            ramps[f"{muscle.prefix}_force_N"] = np.asarray(frc)
            ramps[f"{muscle.prefix}_baseline_N"] = np.asarray([base])
            found[muscle] = th
            self._event("calibration_ramp", f"{muscle.value}: Imin {th[0]:g} mA, Imax "
                                            f"{th[1]:g} mA ({len(cur)} steps)")
        return make_calibration(found[Muscle.EXTENSOR], found[Muscle.FLEXOR], c, ramps)

    def _ramp(self, muscle: Muscle):
        c = self.config.calibration
        fs = self.config.protocol.fs_Hz
        n_base = max(1, int(round(c.baseline_s * fs)))
        if self._check_interrupts(calibrating=True):
            raise _RedoRamp
        self._sleep_checking(c.rest_s)  # output off: the force settles before the tare
        zeros = np.zeros(n_base)
        blk = self._stimulate(self._checked(zeros, zeros), n=n_base)
        if blk.abort_reason:
            self._check_interrupts(calibrating=True)
            raise _RedoRamp
        baseline = settled_mean_N(blk.force_N[:blk.received], c.settle_fraction)
        cur, frc = [], []
        for I in ramp_currents_mA(c, muscle):
            if self._check_interrupts(calibrating=True):
                raise _RedoRamp
            ext, flex = step_envelopes(c, muscle, float(I), fs)
            n = len(ext)
            blk = self._stimulate(self._checked(ext, flex), n=n)
            if blk.abort_reason:
                self._event("calibration_step_aborted",
                            f"{muscle.value} at {I:g} mA: {blk.abort_reason}")
                self._check_interrupts(calibrating=True)
                raise _RedoRamp
            force = settled_mean_N(blk.force_N[:blk.received], c.settle_fraction) - baseline
            cur.append(float(I))
            frc.append(force)
            self._notify("on_calibration_step", muscle.value, float(I), force)
            if abs(force) >= c.force_ceiling_N:
                self._event("calibration_force_ceiling",
                            f"{muscle.value} at {I:g} mA: {force:.2f} N >= ceiling "
                            f"{c.force_ceiling_N:g} N; ramp stopped")
                break
            if detect_thresholds(cur, frc, muscle, c.Fmin_N, c.Fmax_N).complete:
                break
        return require_thresholds(cur, frc, muscle, c), cur, frc, baseline


class _RedoRamp(Exception):
    """Internal: a ramp was interrupted (trip / pause); run it again from the start."""


def _cal_text(cal: Calibration) -> str:
    return (f"Iemin {cal.Iemin_mA:g} mA, Iemax {cal.Iemax_mA:g} mA, Ifmin {cal.Ifmin_mA:g} "
            f"mA, Ifmax {cal.Ifmax_mA:g} mA (Fmin {cal.Fmin_N:g} N, Fmax {cal.Fmax_N:g} N)")
