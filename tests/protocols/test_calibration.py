"""Calibration: ramp plans, Imin/Imax detection with the sign convention, manual entry."""

import numpy as np
import pytest

from nmsid.protocols.calibration import (
    Muscle,
    detect_thresholds,
    manual_calibration,
    ramp_currents_mA,
    require_thresholds,
    settled_mean_N,
    step_envelopes,
)
from nmsid.protocols.config import CalibrationConfig, ManualCurrents
from nmsid.protocols.errors import CalibrationError


def test_ramp_plan_half_mA_steps_to_the_ceiling():
    c = CalibrationConfig(ceiling_ext_mA=5.0, ceiling_flex_mA=3.2)
    assert np.allclose(ramp_currents_mA(c, Muscle.EXTENSOR), np.arange(1, 11) * 0.5)
    assert ramp_currents_mA(c, Muscle.FLEXOR)[-1] == 3.0


def test_detection_extensor_and_flexor_sign():
    cur = np.arange(1, 9) * 0.5
    f = np.array([0.0, 0.1, 0.49, 0.5, 2.0, 4.99, 5.0, 7.0])
    r = detect_thresholds(cur, f, Muscle.EXTENSOR, 0.5, 5.0)
    assert (r.Imin_mA, r.Imax_mA) == (2.0, 3.5)
    r = detect_thresholds(cur, -f, Muscle.FLEXOR, 0.5, 5.0)
    assert (r.Imin_mA, r.Imax_mA) == (2.0, 3.5)
    # the wrong sign never reaches the thresholds
    r = detect_thresholds(cur, -f, Muscle.EXTENSOR, 0.5, 5.0)
    assert r.Imin_mA is None and not r.complete


def test_incomplete_or_degenerate_ramps_are_refused():
    c = CalibrationConfig()
    with pytest.raises(CalibrationError, match="never reached Fmin"):
        require_thresholds([0.5, 1.0], [0.0, 0.1], Muscle.EXTENSOR, c)
    with pytest.raises(CalibrationError, match="never Fmax"):
        require_thresholds([0.5, 1.0], [0.6, 1.0], Muscle.EXTENSOR, c)
    with pytest.raises(CalibrationError, match="one step"):
        require_thresholds([0.5, 1.0], [0.0, 6.0], Muscle.EXTENSOR, c)
    assert require_thresholds([0.5, 1.0, 1.5], [0.0, 1.0, 6.0], Muscle.EXTENSOR, c) == (1.0, 1.5)


def test_step_envelopes_and_settled_mean():
    c = CalibrationConfig(hold_s=0.01)
    e, f = step_envelopes(c, Muscle.FLEXOR, 3.0, 2000.0)
    assert len(e) == 20 and np.all(e == 0) and np.all(f == 3.0)
    assert settled_mean_N(np.r_[np.zeros(5), np.ones(5)], 0.5) == 1.0


def test_manual_entry_validated():
    c = CalibrationConfig(ceiling_ext_mA=10, ceiling_flex_mA=10)
    cal = manual_calibration(ManualCurrents(1, 5, 2, 6), c)
    assert (cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA, cal.Ifmax_mA) == (1, 5, 2, 6)
    with pytest.raises(CalibrationError, match="ceiling"):
        manual_calibration(ManualCurrents(1, 12, 2, 6), c)
