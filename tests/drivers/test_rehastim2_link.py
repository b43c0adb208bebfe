"""The RehaStim2 driver on a link that loses, corrupts or delays packets (issue 37, items
1, 2, 7): a stop confirmed by the device (ScienceMode2 5.3), Busy replies that are not
faults (SM2 5.1, 1.3), a wrong-mode reply to an update that crossed the stop.

Timing: the fake device runs on the real monotonic clock, but every assertion about when
the output ended reads the DEVICE's own record (``dev.stops``, the time its watchdog or a
stop acted): a watchdog expiry is dated by the last valid packet the device received, so
it does not depend on how fast this machine schedules the driver's threads. Waits are
generous bounds (seconds) on conditions, never sleeps that must be long enough.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest

from nmsid.drivers import rehastim2_protocol as sm2
from nmsid.drivers.interfaces import CheckedWaveform, StimulatorState
from nmsid.drivers.rehastim2 import Rehastim2Stimulator
from nmsid.drivers.rehastim2_link import STOP_CONFIRM_S
from nmsid.testing.fakes.fake_rehastim2 import FakeRehastim2

LOGGER = "nmsid.drivers.rehastim2"


def connect(dev: FakeRehastim2) -> Rehastim2Stimulator:
    stim = Rehastim2Stimulator("FAKE", ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                               extensor_channel=1, flexor_channel=2, open_port=dev.open)
    stim.connect()
    return stim


def running(dev: FakeRehastim2, stim: Rehastim2Stimulator, mA: float = 10.0,
            seconds: float = 5.0) -> None:
    n = int(seconds * 1000)
    stim.load(CheckedWaveform(np.full(n, mA), np.zeros(n), 1000.0, 1000.0, 20.0, 20.0))
    stim.arm()
    stim.start()
    until(lambda: dev.mode == 2 and dev.updates, "the device stimulating")


def until(cond, what: str, timeout_s: float = 10.0) -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout_s, f"timed out waiting for {what}"
        time.sleep(0.005)


def operator_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == LOGGER and r.levelno >= logging.WARNING]


@pytest.mark.parametrize("fault", ["lose", "corrupt"])
def test_a_lost_or_corrupted_stop_is_resent_and_confirmed(fault, caplog):
    caplog.set_level(logging.WARNING, logger=LOGGER)
    dev = FakeRehastim2()
    stim = connect(dev)
    try:
        running(dev, stim)
        if fault == "lose":
            dev.lose_next(sm2.STOP_CLM)      # SM2 5.2: the line lost it
        else:
            dev.corrupt_next(sm2.STOP_CLM)   # SM2 4.3 / 5.2: ack -1, not executed
        t_stop = dev.clock()
        stim.stop_now()
        assert dev.mode == 0                 # confirmed before stop_now returned
        assert dev.stops and dev.stops[-1] <= t_stop + 1.2   # as the fake adds it
        assert dev.amplitude_mA_at(1, dev.clock())[0] == 0
        st = stim.status()
        assert st.state is StimulatorState.STOPPED and not st.output_active and not st.error
        [line] = operator_lines(caplog)       # one line: what happened, and that it held
        assert "resent, now confirmed" in line
        assert [p.command for p in dev.received].count(sm2.STOP_CLM) >= 1
        assert dev.lost or fault == "corrupt"
        stim.load(CheckedWaveform(np.full(100, 4.0), np.zeros(100), 1000.0, 1000.0,
                                  20.0, 20.0))
        stim.arm()                            # the next trial needs no reconnect
    finally:
        stim.disconnect()


def test_an_outage_that_loses_every_stop_ends_by_the_device_watchdog(caplog):
    caplog.set_level(logging.WARNING, logger=LOGGER)
    dev = FakeRehastim2()
    stim = connect(dev)
    try:
        running(dev, stim)
        dev.line_down(60.0)                   # nothing gets through, either way
        t_stop = dev.clock()
        stim.stop_now()
        st = stim.status()
        assert st.state is StimulatorState.ERROR and not st.output_active
        assert "did not confirm the stop" in st.error and "watchdog" in st.error
        n_written = len(dev.lost)
        stim.stop_now()                       # the engine's second stop: still silent
        until(lambda: dev.mode == 0, "the device's watchdog", timeout_s=10.0)
        # SM2 5.2: the device stopped itself 1.2 s after the last packet it received,
        # which came before stop_now: within 1.2 s of stop_now, on the device's clock.
        # Compared as the fake computes it (last packet + 1.2): on Windows' 15.625 ms clock
        # the last packet and t_stop can share a tick, and (t + 1.2) - t is 1.2000000000002
        assert dev.watchdog_expiries == 1 and dev.stops[-1] <= t_stop + 1.2
        time.sleep(3 * 0.4)                   # three keep-alive intervals: none was sent
        assert len(dev.lost) == n_written
        lines = operator_lines(caplog)
        assert len(lines) == 1 and "did not confirm the stop" in lines[0]
    finally:
        stim.disconnect()


def test_a_short_outage_is_outlasted_by_the_resends():
    dev = FakeRehastim2()
    stim = connect(dev)
    try:
        running(dev, stim)
        dev.line_down(0.15)                   # 100 ms class outage (issue 37 item 1)
        t_stop = dev.clock()
        stim.stop_now()
        assert dev.mode == 0 and dev.stops[-1] - t_stop <= 1.2
        assert stim.status().state is StimulatorState.STOPPED
        assert STOP_CONFIRM_S > 0.15
    finally:
        stim.disconnect()


def test_an_update_crossing_the_stop_leaves_no_error():
    dev = FakeRehastim2()
    stim = connect(dev)
    try:
        running(dev, stim)
        stim.stop_now()
        # an update that was on the wire when the stop went out: the device answers -3
        # wrong mode (SM2 Figure 4: StartChannelListMode after the stop, in start mode)
        stim._write(sm2.START_CLM, stim._pulse_data(4, 0))
        until(lambda: any(p.command == sm2.START_CLM for p in dev.received[-1:]), "update")
        time.sleep(0.1)                       # the link thread reads the -3 reply
        st = stim.status()
        assert st.state is StimulatorState.STOPPED and not st.error, st
        stim.arm()                            # no reconnect needed
        assert dev.mode == 1
    finally:
        stim.disconnect()


def test_busy_replies_are_skipped_updates_not_faults():
    # 10 % of updates answered -8 busy (SM2 5.1), acks 15 ms after each update
    dev = FakeRehastim2(response_latency_s=0.015, busy_fraction=0.1, seed=4)
    stim = connect(dev)
    try:
        n = 1500                                # 1.5 s: 60 updates at 40 Hz
        stim.load(CheckedWaveform(np.full(n, 6.0), np.zeros(n), 1000.0, 1000.0, 20.0, 20.0))
        stim.arm()
        stim.start()
        until(lambda: stim.status().state is not StimulatorState.RUNNING, "the trial end")
        st = stim.status()
        assert st.state is StimulatorState.STOPPED and not st.error, st
        s = stim.delivery_summary()
        assert s["updates_busy"] == dev.busy_replies > 0
        assert s["updates_acknowledged"] + s["updates_busy"] + s["updates_unanswered"] \
            == s["updates_sent"]
        assert s["ended_by"] == "completed" and not s["update_errors"]
        assert set(s["channels"]["extensor"]["pulse_current_mA"]) == {6}
        assert dev.mode == 0
    finally:
        stim.disconnect()


def test_updates_wait_for_their_predecessors_ack():
    # a device slow to answer (24 ms, the README's upper latency): the driver waits, so
    # the device never has an update arrive before its predecessor's ack
    dev = FakeRehastim2(response_latency_s=0.024)
    stim = connect(dev)
    try:
        n = 1000
        stim.load(CheckedWaveform(np.full(n, 6.0), np.zeros(n), 1000.0, 1000.0, 20.0, 20.0))
        stim.arm()
        stim.start()
        until(lambda: stim.status().state is not StimulatorState.RUNNING, "the trial end")
        assert dev.busy_replies == 0
        assert stim.status().state is StimulatorState.STOPPED
    finally:
        stim.disconnect()
