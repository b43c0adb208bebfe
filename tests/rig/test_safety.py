"""The interlock: the waveform gate, the rules, trip -> output zero first -> latch."""

import threading
import time

import numpy as np
import pytest

from nmsid.drivers.interfaces import (
    AcquisitionFlags,
    CurrentLimitError,
    ForceChunk,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.protocols.config import InterlockConfig
from nmsid.rig.safety import (
    AcquisitionFlagsRule,
    EStopRule,
    ForceLimitRule,
    Interlock,
    InterlockTripped,
    Observation,
    StallRule,
    StimulatorRule,
    check_waveform,
)


class Stim:
    def __init__(self):
        self.log = []
        self.state = StimulatorState.IDLE
        self.err = ""

    def start(self):
        self.log.append("start")

    def stop_now(self):
        self.log.append("stop")

    def status(self):
        return StimulatorStatus(StimulatorState.ERROR if self.err else self.state, False,
                                self.err)


def test_check_waveform_uses_the_lower_ceiling():
    w = check_waveform([1.0, 9.0], [2.0, 3.0], fs_Hz=2000, carrier_Hz=1000,
                       ceiling_ext_mA=10, ceiling_flex_mA=20, device_max_mA=16)
    assert (w.ceiling_ext_mA, w.ceiling_flex_mA) == (10, 16)
    with pytest.raises(CurrentLimitError, match="exceeds the ceiling 16"):
        check_waveform([1.0], [16.5], fs_Hz=2000, carrier_Hz=1000, ceiling_ext_mA=10,
                       ceiling_flex_mA=20, device_max_mA=16)
    with pytest.raises(CurrentLimitError):
        check_waveform([np.nan], [1.0], fs_Hz=2000, carrier_Hz=1000, ceiling_ext_mA=10,
                       ceiling_flex_mA=20, device_max_mA=16)
    with pytest.raises(CurrentLimitError):
        check_waveform([1.0], [1.0], fs_Hz=2000, carrier_Hz=1000, ceiling_ext_mA=-1,
                       ceiling_flex_mA=20, device_max_mA=16)


def test_rules_validate_thresholds_and_say_why():
    with pytest.raises(ValueError):
        ForceLimitRule(0)
    with pytest.raises(ValueError):
        StallRule(float("nan"))
    r = ForceLimitRule(10)
    assert r.check(Observation(0.0, chunk=ForceChunk(100, np.array([1.0, -12.0])))
                   ).startswith("force -12.00 N at sample 101")
    assert "not finite" in ForceLimitRule(10).check(
        Observation(0.0, chunk=ForceChunk(0, np.array([np.nan]))))
    s = StallRule(0.1)
    s.start(1.0)
    assert s.check(Observation(1.05, no_samples=True)) is None
    assert s.check(Observation(1.15)) is None              # not a read without samples
    assert "no force samples for 150 ms" in s.check(Observation(1.15, no_samples=True))
    s.reset()
    assert s.check(Observation(1.16, chunk=ForceChunk(0, np.zeros(3)))) is None  # fed
    assert s.check(Observation(1.20, no_samples=True)) is None
    f = AcquisitionFlagsRule()
    assert "over-range" in f.check(Observation(0.0, chunk=ForceChunk(
        0, np.zeros(2), flags=AcquisitionFlags(over_range=True))))
    assert "jumped" in AcquisitionFlagsRule().check(
        Observation(0.0, chunk=ForceChunk(50, np.zeros(2)), expected_index=40))
    assert AcquisitionFlagsRule(over_range=False).check(Observation(0.0, chunk=ForceChunk(
        0, np.zeros(2), flags=AcquisitionFlags(over_range=True)))) is None


# one observation that each rule, and only it, finds wrong
_WRONG = {
    "acquisition": Observation(0.0, chunk=ForceChunk(
        0, np.zeros(2), flags=AcquisitionFlags(overrun=True))),
    "force_limit": Observation(0.0, chunk=ForceChunk(0, np.array([0.0, 1e6]))),
    "sensor_stream": Observation(99.0, no_samples=True),
    "stimulator": Observation(0.0, stimulator_status=StimulatorStatus(
        StimulatorState.DISCONNECTED, False, "")),
    "estop": Observation(0.0, switch_pressed=True),
}


def test_every_rule_has_one_check_signature_and_the_interlock_asks_each():
    il = Interlock(InterlockConfig(), Stim())
    assert [type(r) for r in il.rules] == [AcquisitionFlagsRule, ForceLimitRule, StallRule,
                                           StimulatorRule, EStopRule]
    il.stall.start(0.0)
    for name, obs in _WRONG.items():
        # only the rule it is meant for objects to each observation
        assert [r.name for r in il.rules if r.check(obs)] == [name]
        trip = il.check(obs)
        assert trip is not None and trip.rule == name, name
        assert il.latched and il.stimulator.log[-1] == "stop"
        il.rearm()
        il.stall.start(0.0)
    assert il.check(Observation(0.5, chunk=ForceChunk(0, np.zeros(4)))) is None


def test_trip_stops_first_latches_and_reports_once():
    stim = Stim()
    trips = []

    def on_trip(t):
        trips.append(t)
        assert stim.log and stim.log[0] == "stop"  # output zero before anyone hears of it

    il = Interlock(InterlockConfig(), stim, on_trip=on_trip)
    il.start_output()
    t = il.trip("force_limit", "too much")
    assert stim.log[:2] == ["start", "stop"] and il.latched
    il.estop("second")
    assert len(trips) == 1 and il.trip_info.rule == "force_limit"
    with pytest.raises(InterlockTripped, match="force_limit"):
        il.start_output()
    assert stim.log.count("start") == 1
    st = il.status()
    assert st["latch"][0] is False and st["force_limit"] == (False, "too much")
    il.rearm()
    assert not il.latched and il.status()["latch"] == (True, "clear")
    il.start_output()
    assert t.rule == "force_limit"


def test_stimulator_rule_and_disconnect():
    stim = Stim()
    il = Interlock(InterlockConfig(), stim)
    assert il.check_stimulator() is None
    stim.err = "overcurrent"
    assert "overcurrent" in il.check_stimulator().detail

    class Broken(Stim):
        def status(self):
            raise OSError("USB gone")
    il2 = Interlock(InterlockConfig(), Broken())
    assert "disconnected" in il2.check_stimulator().detail


class Switch:
    def __init__(self):
        self.pressed = False
        self.broken = False

    def is_pressed(self):
        if self.broken:
            raise OSError("cable")
        return self.pressed

    def close(self):
        pass


def _wait(cond, timeout=2.0):
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout:
            return False
        time.sleep(0.001)
    return True


def test_hardware_switch_watcher_trips_and_blocks_rearm():
    stim, sw = Stim(), Switch()
    il = Interlock(InterlockConfig(), stim, estop_input=sw)
    il.start_watcher()
    try:
        sw.pressed = True
        assert _wait(lambda: il.latched)
        assert il.trip_info.rule == "estop" and "switch" in il.trip_info.detail
        with pytest.raises(InterlockTripped, match="still pressed"):
            il.rearm()
        sw.pressed = False
        il.rearm()
        sw.broken = True  # fail-safe: unreadable switch reads as pressed
        assert _wait(lambda: il.latched)
    finally:
        il.stop_watcher()


def test_estop_from_another_thread():
    stim = Stim()
    il = Interlock(InterlockConfig(), stim)
    th = threading.Thread(target=il.estop, args=("GUI button",))
    th.start()
    th.join()
    assert il.latched and stim.log[0] == "stop" and il.trip_info.detail == "GUI button"


def test_the_block_level_faults_trip_the_named_rule_with_output_zero_first():
    stim = Stim()
    il = Interlock(InterlockConfig(stall_timeout_s=0.2), stim)
    assert il.stall_timeout_s == 0.2
    for fault, rule in ((il.stimulator_fault, "stimulator"),
                        (il.acquisition_fault, "acquisition"),
                        (il.stream_stalled, "sensor_stream")):
        trip = fault("what happened")
        assert (trip.rule, trip.detail) == (rule, "what happened")
        assert il.latched and stim.log[-1] == "stop"
        il.rearm()
    il.watch_stream(1.0)
    assert il.check_stall(1.1) is None and il.check_stall(1.3).rule == "sensor_stream"
    il.rearm()
    il.unwatch_stream()
    assert il.check_stall(9.0) is None


def test_force_rule_speaks_the_joints_quantity_and_unit():
    # a knee session's limit is in N m (protocols/joints.py): the trip says so
    from nmsid.protocols.joints import JOINTS
    from nmsid.rig.safety import ForceLimitRule
    knee = JOINTS["knee"]
    rule = ForceLimitRule(knee.limit, knee.quantity, knee.unit)
    assert rule.detail == "ok (limit 150 N m)"
    verdict = rule.check(Observation(0.0, chunk=ForceChunk(7, np.array([10.0, 151.0]))))
    assert verdict == ("torque 151.00 N m at sample 8 is beyond the limit +/-150 N m")
    assert rule.check(Observation(0.0, chunk=ForceChunk(0, np.array([149.0, -149.0])))) is None
    interlock = Interlock(InterlockConfig(force_limit_N=150.0), None, joint=knee)
    assert interlock.force.unit == "N m"
