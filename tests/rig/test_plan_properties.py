"""Properties of plans and the one preflight (issue 36): over random plans, calibrations
and controllers, no commanded sample is above its channel's calibrated maximum, and every
invalid plan is refused before the first output."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.analysis.control.design import design_controller
from nmsid.analysis.control.targets import Target
from nmsid.analysis.twin import Twin
from nmsid.protocols.config import config_from_dict, load_config
from nmsid.protocols.plan import Plan, PlanItem, PlanRefused, RigLimits, item_problem, preflight
from nmsid.protocols.session_file import Calibration
from nmsid.protocols.waveforms import currents_mA
from nmsid.rig.engine import Engine, TripPolicy
from nmsid.rig.tracking import TrackingEngine, TrackingSession, TrackingStream
from nmsid.rig.trials import IdentificationSession
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.participant import default_participant

WIDE = st.one_of(st.floats(-2.0, 3.0), st.sampled_from([math.nan, math.inf, -math.inf]))
KINDS = st.sampled_from(["identification", "reference", "tracking", "relay", "dry_run",
                         "walking"])


@st.composite
def calibrations(draw):
    Iemin = draw(st.floats(0.5, 10.0))
    Ifmin = draw(st.floats(0.5, 10.0))
    return Calibration(Iemin, Iemin + draw(st.floats(0.5, 20.0)), Ifmin,
                       Ifmin + draw(st.floats(0.5, 20.0)))


def _mostly(valid, invalid):
    """Mostly valid values (so that accepted plans are common), sometimes anything."""
    return st.one_of(valid, valid, valid, invalid)


@st.composite
def items(draw, index=0):
    a, b = draw(st.floats(0.0, 1.0)), draw(st.floats(0.0, 1.0))
    rE = draw(_mostly(st.just((min(a, b), max(a, b))), st.tuples(WIDE, WIDE)))
    target = draw(st.none() | _mostly(
        st.tuples(st.floats(-20, 0), st.floats(0, 20)), st.tuples(WIDE, WIDE)))
    return PlanItem(index, draw(_mostly(KINDS.filter(lambda k: k != "walking"), KINDS)),
                    draw(_mostly(st.floats(0.01, 1.0), WIDE)),
                    draw(_mostly(st.floats(0.1, 600.0), st.floats(-1.0, 5000.0) | WIDE)),
                    rE_range=rE, target_range_N=target)


@st.composite
def plans(draw):
    n = draw(st.integers(1, 4))
    return Plan("random", tuple(draw(items(index=k)) for k in range(n)))


LIMITS = st.builds(RigLimits, st.floats(0.0, 40.0), st.floats(0.0, 40.0),
                   st.floats(1.0, 100.0), st.none() | st.floats(1.0, 50.0))


@given(plan=plans(), limits=LIMITS, cal=calibrations(), rE=st.floats(0.0, 1.0))
@settings(max_examples=300, deadline=None)
def test_an_accepted_plan_commands_nothing_above_a_calibrated_maximum(plan, limits, cal, rE):
    try:
        preflight(plan, limits, cal)
    except PlanRefused as exc:
        assert "\n" not in str(exc) and any(item_problem(it, limits, cal) for it in plan)
        return
    for it in plan:
        lo, hi = it.rE_range
        r = lo + rE * (hi - lo)        # any rE the item may command
        Ie, If = (float(x) for x in currents_mA(r, it.sE, cal.Iemin_mA, cal.Iemax_mA,
                                                cal.Ifmin_mA, cal.Ifmax_mA))
        assert Ie <= cal.Iemax_mA + 1e-9 and If <= cal.Ifmax_mA + 1e-9
        assert Ie <= limits.ceiling_ext_mA + 1e-9 and If <= limits.ceiling_flex_mA + 1e-9
        if limits.device_max_mA is not None:
            assert max(Ie, If) <= limits.device_max_mA + 1e-9
        assert 0 < it.duration_s <= 3600 and math.isfinite(it.sE)


class _Kind(IdentificationSession):
    """The identification schedule, but whatever plan the test draws."""

    def __init__(self, plan):
        self._plan = plan

    def plan(self, engine):
        return self._plan

    def schedule(self, engine):
        from nmsid.protocols.schedule import PlannedTrial
        return [PlannedTrial(it.index, 0.5, 1) for it in self._plan]


@given(plan=plans())
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_every_invalid_plan_is_refused_before_the_first_output(tmp_path, plan):
    cfg = load_config(None)
    rig = make_sim_rig(default_participant())
    path = tmp_path / "p.h5"
    bad = any(item_problem(it, RigLimits.of(cfg)) for it in plan)
    try:
        Engine(cfg, rig, path, session=_Kind(plan), trip_policy=TripPolicy.END_SESSION)
    except PlanRefused as exc:
        assert bad and "\n" not in str(exc)
    else:
        assert not bad
    assert rig.max_sent_mA == (0.0, 0.0) and not path.exists()
    assert not rig.run_records


# -- streamed controllers, on the simulated rig -------------------------------------------
@pytest.fixture(scope="module")
def design():
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    d.baseline["relay_s"] = 1.0
    return d


class _Random:
    """A controller answering a drawn sequence (anything: far outside [0, 1] too)."""

    name = "random"

    def __init__(self, answers, queue):
        self.answers, self.queue = list(answers), queue

    def start(self, target, target_id=""):
        return [self.answers[k % len(self.answers)] for k in range(self.queue)]

    def step(self, j, y):
        return self.answers[j % len(self.answers)]

    def finish(self, means):
        pass


@given(answers=st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=30),
       sE=st.floats(0.05, 3.0), cal=calibrations(),
       ceilings=st.tuples(st.floats(0.0, 50.0), st.floats(0.0, 50.0)))
@settings(max_examples=300, deadline=None)
def test_a_stream_never_commands_above_a_calibrated_maximum(answers, sE, cal, ceilings):
    s = TrackingStream(_Random(answers, 2), np.zeros(8), "", sE, cal, ceilings, 200.0,
                       2000.0, 2, clock=None)
    for a in answers:
        _, Ie, If = s.currents(a)
        assert 0 <= Ie <= min(cal.Iemax_mA, ceilings[0])
        assert 0 <= If <= min(cal.Ifmax_mA, ceilings[1])


MANUAL = {"participant": "Q01", "calibration": {"manual": {
    "Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5, "Ifmax_mA": 8.0}}}


@given(answers=st.lists(st.floats(-10.0, 10.0), min_size=1, max_size=20))
@settings(max_examples=6, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_tracking_sessions_with_random_controllers_stay_below_the_calibration(
        tmp_path_factory, design, answers):
    rig = make_sim_rig(default_participant(seed=3))
    cfg = config_from_dict(MANUAL).with_protocol(rest_s=0.0)
    target = Target("s", "sine", {"mean_N": 0.0, "amplitude_N": 1.0, "f_Hz": 1.0}, 1.0, 0.2)
    real = TrackingSession._controller_for

    def controller(self, item):
        return _Random(answers, design.queue) if item.controller != "relay" else \
            real(self, item)
    TrackingSession._controller_for = controller
    try:
        eng = TrackingEngine(cfg, rig, tmp_path_factory.mktemp("q") / "q.h5", design=design,
                             targets=[target], trip_policy=TripPolicy.END_SESSION)
        eng.run()
    finally:
        TrackingSession._controller_for = real
    sent_e, sent_f = rig.max_sent_mA
    assert sent_e <= 9.5 + 1e-9 and sent_f <= 8.0 + 1e-9
