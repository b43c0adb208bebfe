"""Session times from a clock that does not step (issue 26, 5): monotonic offsets from a
recorded UTC start; steps of the computer's clock recorded as events, never followed."""

import datetime as dt

import numpy as np

from nmsid.export.nwb import trial_start_times_s
from nmsid.protocols.session_file import Calibration, Trial, read_session
from nmsid.rig.session_clock import SessionClock
from nmsid.rig.session_log import SessionLog


class Clocks:
    """A wall clock that an operator (or NTP) may set, and a monotonic one."""

    def __init__(self):
        self.wall = dt.datetime(2026, 11, 24, 10, 0, tzinfo=dt.UTC).timestamp()
        self.mono = 1000.0

    def advance(self, s):
        self.wall += s
        self.mono += s


def _trial(i, n=200):
    x = np.linspace(0, 1, n)
    return Trial(sE=0.3 + 0.1 * i, repeat=1, fs_Hz=100.0, rE=x, I_ext_mA=x, I_flex_mA=x,
                 force_N=x, extra_attrs={"schedule_index": i})


def test_a_wall_clock_step_is_an_event_and_times_stay_monotonic(tmp_path):
    c = Clocks()
    path = tmp_path / "T.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=1,
                            backend="test", schedule_json="[]",
                            created_utc="2026-11-24T10:00:00Z")
    log.clock = SessionClock(wall=lambda: c.wall, mono=lambda: c.mono)
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    starts = []
    for i, jump_s in enumerate([0.0, -3600.0, 0.0, +7200.0]):
        c.wall += jump_s  # the computer's clock is set back, then forward
        log.begin_trial(_trial(i))
        c.advance(2.0)    # the trial lasts 2 s
        t = _trial(i)
        log.end_trial(t)
        starts.append(t.started_utc)
        c.advance(1.0)    # rest
    log.event("note", "after the steps")
    assert log.finish() is True
    s = read_session(path)
    assert [t.started_utc for t in s.trials] == starts == [
        "2026-11-24T10:00:00.000Z", "2026-11-24T10:00:03.000Z",
        "2026-11-24T10:00:06.000Z", "2026-11-24T10:00:09.000Z"]
    steps = [e for e in s.events if e.kind == "clock_step"]
    assert len(steps) == 2
    assert "stepped by -3600.000 s" in steps[0].detail
    assert "stepped by +7200.000 s" in steps[1].detail
    assert [e.utc for e in s.events] == sorted(e.utc for e in s.events)  # never backwards
    # the NWB export places the trials on the same line: 3 s apart, no hour-long shift
    assert np.allclose(trial_start_times_s(s), [0.0, 3.0, 6.0, 9.0])


def test_small_differences_are_not_steps_and_perf_counter_is_the_default():
    c = Clocks()
    clock = SessionClock(wall=lambda: c.wall, mono=lambda: c.mono)
    c.advance(10.0)
    c.wall += 0.5  # NTP slewing, scheduling jitter
    assert clock.step() == "" and clock.utc() == "2026-11-24T10:00:10.000Z"
    import time
    default = SessionClock()
    assert default._mono is time.perf_counter
