"""Tracking sessions: closed loop through the engine, interlock and E-stop (rig.tracking)."""

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from nmsid.analysis.control.design import design_controller, rmse_pct_of_range
from nmsid.analysis.control.targets import Target
from nmsid.analysis.twin import Twin
from nmsid.protocols.config import load_config
from nmsid.protocols.session_file import Calibration, read_session, validate_session
from nmsid.rig.engine import TripPolicy
from nmsid.rig.tracking import (
    TrackingControllerError,
    TrackingEngine,
    TrackingStream,
    tracking_plan,
)
from nmsid.sim_backends import Fault, FaultKind, make_sim_rig
from nmsid.sim_backends.participant import default_participant

SHORT_TARGETS = [Target("sine-1Hz", "sine", {"mean_N": 0.0, "amplitude_N": 1.5, "f_Hz": 1.0},
                        2.0, 0.5)]


@pytest.fixture(scope="module")
def design():
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    d.baseline["relay_s"] = 2.0
    return d


def _session(tmp_path, design, faults=(), name="t.h5", observer=None):
    rig = make_sim_rig(default_participant(seed=2), faults=list(faults))
    cfg = load_config(None).with_protocol(rest_s=0.0)
    path = tmp_path / name
    eng = TrackingEngine(cfg, rig, path, design=design, targets=SHORT_TARGETS,
                         trip_policy=TripPolicy.END_SESSION, observer=observer)
    return rig, path, eng.run()


def test_plan_tunes_the_baseline_first_then_interleaves():
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    plan = tracking_plan(d)
    assert plan[0].controller == "relay"
    pairs = [(plan[k].controller, plan[k + 1].controller) for k in range(1, len(plan), 2)]
    assert pairs[0] == ("twin", "baseline") and pairs[1] == ("baseline", "twin")
    assert all(plan[k].target_json == plan[k + 1].target_json for k in range(1, len(plan), 2))


def test_tracking_session_records_validates_and_the_twin_wins(tmp_path, design):
    rig, path, summary = _session(tmp_path, design)
    assert summary.ended_by == "schedule complete" and summary.n_completed == 3
    assert validate_session(path) == []
    s = read_session(path)
    assert s.attrs["session_kind"] == "tracking"
    assert json.loads(s.attrs["tracking_controller_json"])["Kc"] == design.Kc
    kinds = [(t.extra_attrs["trial_kind"], t.extra_attrs["controller"]) for t in s.trials]
    assert kinds == [("relay", "relay"), ("tracking", "twin"), ("tracking", "baseline")]
    err = {}
    ce, cf = design.current_limits_mA(s.calibration)
    for t in s.trials:
        tg = Target.from_json(t.extra_attrs["target_json"])
        stream = json.loads(t.extra_attrs["stream_json"])
        # the loop: one update queued ahead, 5 ms updates: 5 ms + one sample
        assert stream["latency_median_s"] == pytest.approx(0.005 + 1 / 2000, abs=1e-9)
        assert stream["late_updates"] == 0 and stream["n_updates"] > 0
        # the stream's ceilings are the calibration's limits at the controller's sE
        assert stream["ceiling_ext_mA"] <= ce + 1e-12 and stream["ceiling_flex_mA"] <= cf + 1e-12
        assert t.I_ext_mA.max() <= min(ce, stream["ceiling_ext_mA"]) + 1e-12
        assert t.I_flex_mA.max() <= min(cf, stream["ceiling_flex_mA"]) + 1e-12
        if t.extra_attrs["controller"] != "relay":
            r = tg.force_at(np.arange(t.n_samples) / t.fs_Hz)
            err[t.extra_attrs["controller"]] = rmse_pct_of_range(t.force_N, r,
                                                                 int(tg.lead_s * t.fs_Hz))
    assert "pid_json" in s.trials[2].extra_attrs
    assert err["twin"] < 0.5 * err["baseline"]
    # the stimulator delivered what the file says was commanded (within the 1 uA step)
    last = rig.run_records[-1]
    I_e, _, _ = rig.world.output(last.N_trigger, last.N_trigger + s.trials[-1].n_samples)
    assert np.all(np.abs(I_e - s.trials[-1].I_ext_mA) <= 1e-3 + 1e-12)


def test_estop_mid_tracking_ends_with_output_zero(tmp_path, design):
    # trial 0 is the relay (the calibration ramps are single-muscle runs), trial 1 the twin
    rig, path, summary = _session(tmp_path, design,
                                  [Fault(FaultKind.ESTOP, trial=1, at_s=1.2)])
    assert summary.trip is not None and summary.trip.rule == "estop"
    assert validate_session(path) == []
    s = read_session(path)
    t = s.trials[-1]
    assert t.status == "aborted" and t.extra_attrs["controller"] == "twin"
    assert 0 < t.n_samples < 2.5 * 2000
    zero = [z for z in rig.output_zero_events if z.reason == "stop_now"]
    assert zero, "stop_now was not called"
    rec = rig.run_records[-1]
    I_e, I_f, _ = rig.world.output(rec.N_trigger, rec.N_trigger + 5 * 2000)
    stop = zero[0].sample_index - rec.N_trigger
    assert I_e[:stop].max() > 0 and not I_e[stop:].any() and not I_f[stop:].any()
    assert stop <= int(1.2 * 2000) + 10


class _Wild:
    """A controller that answers whatever it is given to answer."""

    name = "wild"
    queue = 2

    def __init__(self, answers):
        self.answers = list(answers)

    def start(self, target, target_id=""):
        return [0.5, 0.5]

    def step(self, j, y):
        return self.answers[j % len(self.answers)]


CAL = Calibration(2.0, 9.5, 1.5, 8.0, 0.5, 5.0)


@given(rE=st.floats(allow_nan=False, allow_infinity=True), sE=st.floats(0.05, 1.0),
       ce=st.floats(0.0, 16.0), cf=st.floats(0.0, 16.0))
def test_no_stream_current_above_its_ceiling_whatever_the_controller_asks(rE, sE, ce, cf):
    s = TrackingStream(_Wild([rE]), np.zeros(4), "", sE, CAL, (ce, cf), 200.0, 2000.0, 2,
                       clock=None)
    if not math.isfinite(rE):
        with pytest.raises(TrackingControllerError):
            s.currents(rE)
        return
    r, Ie, If = s.currents(rE)
    assert 0.0 <= r <= 1.0 and 0.0 <= Ie <= ce and 0.0 <= If <= cf
    assert Ie <= CAL.Iemin_mA + sE * (CAL.Iemax_mA - CAL.Iemin_mA) + 1e-12
    assert If <= CAL.Ifmin_mA + sE * (CAL.Ifmax_mA - CAL.Ifmin_mA) + 1e-12


def test_a_nan_from_the_controller_trips_and_stops_output(tmp_path, design, monkeypatch):
    from nmsid.rig import tracking
    real = tracking.TrackingSession._controller_for

    def wild(self, entry):
        if entry.controller == "twin":
            return _Wild([0.6] * 50 + [math.nan])
        return real(self, entry)

    monkeypatch.setattr(tracking.TrackingSession, "_controller_for", wild)
    rig, path, summary = _session(tmp_path, design)
    assert summary.trip is not None and "rE = nan" in summary.trip.detail
    s = read_session(path)
    assert s.trials[-1].status == "aborted" and validate_session(path) == []
    assert rig.output_zero_events


def test_each_chunk_of_a_tracking_trial_reports_its_target_for_the_live_plots(tmp_path,
                                                                              design):
    from nmsid.rig.observer import EngineObserver  # noqa: PLC0415

    class Recorder(EngineObserver):
        def __init__(self):
            self.chunks, self.targets = [], []

        def on_chunk(self, index, start_index, force_N, *rest):
            self.chunks.append((index, start_index, len(force_N)))

        def on_target(self, index, start_index, target_N):
            self.targets.append((index, start_index, np.asarray(target_N)))

    rec = Recorder()
    _rig, _path, summary = _session(tmp_path, design, observer=rec)
    assert summary.n_completed == 3
    # one target per chunk, same trial, first sample and length
    assert [(i, lo, len(t)) for i, lo, t in rec.targets] == rec.chunks
    # the sine target of SHORT_TARGETS: mean 0, amplitude 1.5 N around the operating point
    values = np.concatenate([t for _, _, t in rec.targets])
    assert np.all(np.isfinite(values)) and np.ptp(values) > 1.0
