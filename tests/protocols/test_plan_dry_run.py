"""Dry-run plan items (issue 36): their envelope is absolute currents (``max_mA``), held
to the rig's ceilings by the preflight before any calibration exists, and to the
calibration once it does."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols.plan import (
    DRY_RUN_ROLES,
    PlanRefused,
    RigLimits,
    dry_run_plan,
    preflight,
)
from nmsid.protocols.session_file import Calibration

CURRENT = st.one_of(st.floats(-5, 30, allow_nan=False), st.sampled_from(
    [math.nan, math.inf, -math.inf, 0.0, 5.0]))


@settings(max_examples=200, deadline=None)
@given(amplitude=CURRENT, ceiling=st.floats(0.5, 20), channel=st.sampled_from(
    ["extensor", "flexor"]))
def test_an_item_is_refused_before_calibration_exactly_when_outside_the_ceiling(
        amplitude, ceiling, channel):
    plan = dry_run_plan(DRY_RUN_ROLES, channel, amplitude, 1.0, source="p")
    ok = math.isfinite(amplitude) and 0.0 <= amplitude <= ceiling + 1e-9
    limits = RigLimits(ceiling, ceiling, 25.0)
    if ok:
        preflight(plan, limits)
    else:
        with pytest.raises(PlanRefused, match="nothing was stimulated"):
            preflight(plan, limits)


@settings(max_examples=100, deadline=None)
@given(amplitude=st.floats(0.1, 5), cal_max=st.floats(0.1, 5), device=st.floats(0.5, 20))
def test_after_calibration_no_item_commands_above_the_calibrated_maximum(amplitude, cal_max,
                                                                        device):
    plan = dry_run_plan(["download", "streamed"], "flexor", amplitude, 1.0)
    limits = RigLimits(5.0, 5.0, 25.0, device_max_mA=device)
    cal = Calibration(0.0, cal_max, 0.0, cal_max)
    allowed = min(cal_max, 5.0, device)
    if amplitude <= allowed + 1e-9:
        preflight(plan, limits, cal)
        assert all(it.max_current_mA(cal) == (0.0, amplitude) for it in plan)
    else:
        with pytest.raises(PlanRefused, match="flexor current up to .* no trial was run"):
            preflight(plan, limits, cal)


def test_the_e_stop_test_is_last_and_an_unknown_role_is_refused():
    plan = dry_run_plan(["estop", "streamed", "download"], "extensor", 2.0, 1.0)
    assert [it.label for it in plan] == ["dry run, downloaded trial",
                                         "dry run, streamed trial", "dry run, E-stop test"]
    assert [it.index for it in plan] == [0, 1, 2] and plan.kind == "dry_run"
    with pytest.raises(PlanRefused, match="role 'chirp' is unknown"):
        dry_run_plan(["chirp"], "extensor", 2.0, 1.0)
