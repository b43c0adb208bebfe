"""Property tests (hypothesis): whatever the configuration and schedule, no sample sent to
the stimulator exceeds its ceiling; after any fault, output is zero."""

import itertools

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.protocols.config import config_from_dict
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy
from nmsid.rig.states import State

_counter = itertools.count()


@st.composite
def configs(draw):
    n_levels = draw(st.integers(1, 4))
    levels = sorted(draw(st.lists(st.integers(1, 20), min_size=n_levels, max_size=n_levels,
                                  unique=True)))
    ce = draw(st.floats(8.0, 16.0))
    cf = draw(st.floats(9.0, 16.0))
    manual = draw(st.booleans())
    cal = {"hold_s": 0.05, "baseline_s": 0.05, "ceiling_ext_mA": ce, "ceiling_flex_mA": cf,
           "step_mA": draw(st.sampled_from([0.25, 0.5, 1.0]))}
    if manual:
        iemin = draw(st.floats(0.0, 3.0))
        ifmin = draw(st.floats(0.0, 3.0))
        cal["manual"] = {"Iemin_mA": iemin, "Iemax_mA": draw(st.floats(iemin + 0.5, ce)),
                         "Ifmin_mA": ifmin, "Ifmax_mA": draw(st.floats(ifmin + 0.5, cf))}
    return config_from_dict({
        "participant": "H1", "seed": draw(st.integers(0, 2**31)),
        "protocol": {"sE_levels": [v / 20 for v in levels],
                     "repeats": draw(st.integers(1, 2)),
                     "randomisation": draw(st.sampled_from(["blocks", "full"])),
                     "steady_s": draw(st.sampled_from([0.0, 0.1])),
                     "chirp_s": 0.2, "rest_s": 0.0,
                     "rE_amplitude": draw(st.floats(0.0, 0.5)),
                     "chirp_f1_Hz": draw(st.floats(2.0, 50.0))},
        "calibration": cal})


@given(cfg=configs(), device_max=st.floats(10.0, 40.0))
@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_no_sample_above_its_ceiling(tmp_path, fake_rig, cfg, device_max):
    rig = fake_rig()
    rig.stimulator.caps = rig.stimulator.caps.__class__(2, device_max, 0.01, 1e5)
    path = tmp_path / f"p{next(_counter)}.h5"
    try:
        Engine(cfg, rig, path, trip_policy=TripPolicy.END_SESSION).run()
    except ValueError:
        pass  # refused up front (ceiling above the device, or calibration impossible)
    ce = min(cfg.calibration.ceiling_ext_mA, device_max)
    cf = min(cfg.calibration.ceiling_flex_mA, device_max)
    for wf in rig.stimulator.received:
        assert wf.I_ext_mA.max(initial=0) <= ce + 1e-12
        assert wf.I_flex_mA.max(initial=0) <= cf + 1e-12
    assert rig.stimulator.output_active is False


FAULTS = ["stall", "over_range", "spike", "stim_error", "estop"]


@given(fault=st.sampled_from(FAULTS), trial=st.integers(0, 3), at=st.integers(0, 2999),
       seed=st.integers(0, 1000))
@settings(max_examples=20, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_after_any_fault_output_is_zero(tmp_path, fake_rig, small_config, fault, trial, at,
                                        seed):
    rig = fake_rig()
    path = tmp_path / f"f{next(_counter)}.h5"
    eng = Engine(small_config(seed=seed), rig, path, trip_policy=TripPolicy.END_SESSION)
    rig.acquisition.estop_fn = lambda: eng.commands.estop("injected")
    seen = []

    class Obs(EngineObserver):
        def on_trial_started(self, index, planned):
            if index == eng.schedule[trial].index:
                rig.acquisition.faults[fault] = (rig.stimulator.started + 1, at)

        def on_state(self, old, new, reason):
            if new is State.TRIPPED:
                seen.append(rig.stimulator.output_active)
    eng.observer = Obs()
    s = eng.run()
    assert seen == [False]  # tripped, and output was already zero then
    assert rig.stimulator.output_active is False
    sess = read_session(path)
    aborted = [t for t in sess.trials if not t.completed]
    assert len(aborted) == 1 and aborted[0].abort_reason
    assert aborted[0].n_samples <= at + 200  # stopped within one chunk of the fault
    assert s.n_completed == trial and validate_session(path) == []
