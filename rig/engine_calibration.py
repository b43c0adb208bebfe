"""Calibration as the engine runs it: manual, ramps, or the operator's confirmation.

:func:`calibrate` is the engine's calibration phase, a plain function of the one
:class:`nmsid.rig.engine.Engine` (it runs its blocks through the engine's stimulation
step, interlock, journal and command checks); the pure parts (ramp plans, threshold
detection) live in :mod:`nmsid.protocols.calibration`.
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

if TYPE_CHECKING:  # annotations only: nmsid.rig.engine imports this module
    from nmsid.rig.engine import Engine


def calibrate(engine: Engine) -> None:
    """The calibration phase: from the session file (resume), the configuration (manual)
    or the ramps, then the operator's confirmation when ``calibration.confirm`` is set.
    Sets ``engine.calibration``, writes it to the journal and the file, arms the engine.

    Raises
    ------
    CalibrationError
        The ramps failed and no operator confirms the currents.
    """
    c = engine.config.calibration
    if engine.calibration is not None:  # resumed session
        engine._event("calibration", "from the session file (resume)")
        engine._notify("on_calibration_result", engine.calibration)
        return
    cal: Calibration | None
    if c.manual is not None:
        cal = manual_calibration(c.manual, c)
        engine._event("calibration", "entered by hand in the configuration")
    else:
        engine._sm.to(State.CALIBRATING, "ramps")
        try:
            cal = _ramps(engine)
        except CalibrationError as exc:
            engine._event("calibration_failed", str(exc))
            if not c.confirm:
                raise
            cal = None
    if cal is not None:
        engine._notify("on_calibration_result", cal)
    if c.confirm:
        confirmations = engine._confirmations
        confirmations.clear()
        while True:
            engine._wait_operator(lambda: bool(confirmations), "confirm calibration")
            candidate = confirmations.pop(0)
            try:
                check_calibration(candidate, c)
            except CalibrationError as exc:
                engine._event("calibration_refused", str(exc))
                continue
            if cal is not None and not candidate.ramps:
                candidate.ramps = dict(cal.ramps)  # keep the measured ramps
            cal = candidate
            break
        engine._event("calibration_confirmed", _cal_text(cal))
    if cal is None:   # unreachable: without confirm a failed ramp raised above
        raise CalibrationError("no calibration")
    engine._skip_req = False  # a skip pressed during calibration means nothing
    engine.calibration = cal
    engine._open_log.write_calibration(cal)
    engine._event("calibration", _cal_text(cal))
    engine._sm.to(State.ARMED, "calibrated")


def _ramps(engine: Engine) -> Calibration:
    c = engine.config.calibration
    found, ramps = {}, {}
    for muscle in (Muscle.EXTENSOR, Muscle.FLEXOR):
        while True:
            try:
                th, cur, frc, base = _ramp(engine, muscle)
                break
            except _RedoRamp:
                continue
        ramps[f"{muscle.prefix}_I_mA"] = np.asarray(cur)
        ramps[f"{muscle.prefix}_force_N"] = np.asarray(frc)
        ramps[f"{muscle.prefix}_baseline_N"] = np.asarray([base])
        found[muscle] = th
        engine._event("calibration_ramp", f"{muscle.value}: Imin {th[0]:g} mA, Imax "
                                          f"{th[1]:g} mA ({len(cur)} steps)")
    return make_calibration(found[Muscle.EXTENSOR], found[Muscle.FLEXOR], c, ramps)


def _ramp(engine: Engine, muscle: Muscle):
    c = engine.config.calibration
    fs = engine.config.protocol.fs_Hz
    n_base = max(1, int(round(c.baseline_s * fs)))
    if engine._check_interrupts(calibrating=True):
        raise _RedoRamp
    engine._sleep_checking(c.rest_s)  # output off: the force settles before the tare
    zeros = np.zeros(n_base)
    blk = engine._stimulate(engine._checked(zeros, zeros), n=n_base)
    if blk.abort_reason:
        engine._check_interrupts(calibrating=True)
        raise _RedoRamp
    baseline = settled_mean_N(blk.force_N[:blk.received], c.settle_fraction)
    cur: list[float] = []
    frc: list[float] = []
    for I in ramp_currents_mA(c, muscle):
        if engine._check_interrupts(calibrating=True):
            raise _RedoRamp
        ext, flex = step_envelopes(c, muscle, float(I), fs)
        n = len(ext)
        blk = engine._stimulate(engine._checked(ext, flex), n=n)
        if blk.abort_reason:
            engine._event("calibration_step_aborted",
                          f"{muscle.value} at {I:g} mA: {blk.abort_reason}")
            engine._check_interrupts(calibrating=True)
            raise _RedoRamp
        force = settled_mean_N(blk.force_N[:blk.received], c.settle_fraction) - baseline
        cur.append(float(I))
        frc.append(force)
        engine._notify("on_calibration_step", muscle.value, float(I), force)
        if abs(force) >= c.force_ceiling_N:
            engine._event("calibration_force_ceiling",
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
