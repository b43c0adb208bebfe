"""Tests that bite (issue 29, 5): the interlock's trip stops the output FIRST, in the
tripping thread, without waiting for a ``start()`` that blocks inside the gate; and a
second stop follows a start that raced the trip. Through :class:`Interlock` only."""

from __future__ import annotations

import threading
import time

from nmsid.drivers.interfaces import StimulatorState, StimulatorStatus
from nmsid.protocols.config import InterlockConfig
from nmsid.rig.safety import Interlock

START_BLOCKS_S = 0.5


class BlockingStim:
    """A stimulator whose ``start()`` takes half a second (a USB round trip that hangs),
    recording when each call arrives."""

    def __init__(self):
        self.calls: list[tuple[str, float]] = []
        self.started = threading.Event()

    def start(self):
        self.calls.append(("start", time.perf_counter()))
        self.started.set()
        time.sleep(START_BLOCKS_S)

    def stop_now(self):
        self.calls.append(("stop", time.perf_counter()))

    def status(self):
        return StimulatorStatus(StimulatorState.IDLE, False, "")


class FakeSwitch:
    """A hardware E-stop switch as the interlock reads it (``is_pressed``, ``close``)."""

    pressed = False

    def is_pressed(self) -> bool:
        return self.pressed

    def close(self) -> None:
        pass


def test_a_trip_stops_output_at_once_while_start_blocks_in_the_gate():
    stim = BlockingStim()
    lock = Interlock(InterlockConfig(), stim)
    starter = threading.Thread(target=lock.start_output)
    starter.start()
    assert stim.started.wait(2.0)
    t0 = time.perf_counter()
    tripper = threading.Thread(target=lock.trip, args=("force_limit", "test"))
    tripper.start()
    deadline = time.perf_counter() + 2.0
    while not any(k == "stop" for k, _ in stim.calls) and time.perf_counter() < deadline:
        time.sleep(0.001)
    stops = [t for k, t in stim.calls if k == "stop"]
    starter.join()
    tripper.join()
    # output told to stop within 100 ms of the trip, not after start() let go (500 ms)
    assert stops and stops[0] - t0 < 0.1, [(k, t - t0) for k, t in stim.calls]
    assert lock.latched


def test_a_trip_stops_again_after_a_start_that_raced_it():
    stim = BlockingStim()
    lock = Interlock(InterlockConfig(), stim)
    starter = threading.Thread(target=lock.start_output)
    starter.start()
    assert stim.started.wait(2.0)
    lock.trip("force_limit", "test")
    starter.join()
    kinds = [k for k, _ in stim.calls]
    # the last word is a stop that came after the start completed
    start_done = stim.calls[0][1] + START_BLOCKS_S
    assert kinds[-1] == "stop" and stim.calls[-1][1] >= start_done - 0.01, kinds
    assert kinds.count("stop") >= 2


def _chunk(force, **flags):
    import numpy as np

    from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk
    return ForceChunk(0, np.asarray(force, dtype=float), flags=AcquisitionFlags(**flags))


def test_check_chunk_trips_on_force_and_on_each_flag_through_the_interlock():
    from nmsid.rig.safety import Interlock
    for chunk, rule in ((_chunk([1.0, 40.0]), "force_limit"),
                        (_chunk([0.0], sensor_fault=True, detail="AD error"), "acq_flags"),
                        (_chunk([0.0], over_range=True), "acq_flags"),
                        (_chunk([0.0], overrun=True), "acq_flags")):
        stim = BlockingStim()
        lock = Interlock(InterlockConfig(), stim)
        trip = lock.check_chunk(chunk, 0.0)
        assert trip is not None and lock.latched, rule
        assert trip.rule in {r.name for r in lock.rules}
        assert any(k == "stop" for k, _ in stim.calls)
    quiet = Interlock(InterlockConfig(), BlockingStim())
    assert quiet.check_chunk(_chunk([1.0, -2.0]), 0.0) is None and not quiet.latched


def test_stop_watcher_ends_the_switch_thread_and_a_restart_watches_again():
    """stop_watcher must end the polling thread (a session's end); start_watcher after it
    must poll again (the next session in the same GUI window)."""
    import threading  # noqa: PLC0415
    import time  # noqa: PLC0415

    sw = FakeSwitch()
    lock = Interlock(InterlockConfig(), BlockingStim(), estop_input=sw)
    lock.start_watcher()
    assert any(t.name == "nmsid-estop-watcher" for t in threading.enumerate())
    lock.stop_watcher()
    assert not any(t.name == "nmsid-estop-watcher" for t in threading.enumerate())
    lock.start_watcher()
    sw.pressed = True
    deadline = time.monotonic() + 2.0
    while not lock.latched and time.monotonic() < deadline:
        time.sleep(0.005)
    lock.stop_watcher()
    assert lock.latched


def test_the_estop_rules_status_says_whether_a_hardware_switch_is_watched():
    """The operator's status panel tells a rig with a switch from one without, before any
    trip and again after a re-arm."""

    bare = Interlock(InterlockConfig(), BlockingStim())
    assert bare.status()["estop"] == (True, "ok (no hardware switch)")
    sw = FakeSwitch()
    wired = Interlock(InterlockConfig(), BlockingStim(), estop_input=sw)
    assert wired.status()["estop"] == (True, "ok (switch released)")
    sw.pressed = True
    assert wired.check_switch(0.0) is not None
    assert wired.status()["estop"][0] is False
    sw.pressed = False
    wired.rearm()
    assert wired.status()["estop"] == (True, "ok (switch released)")


def test_an_estop_is_logged_as_information_and_a_fault_trip_as_a_warning(caplog):
    """The E-stop is the operator's own act (INFO); a fault is news (WARNING)."""
    import logging  # noqa: PLC0415
    with caplog.at_level(logging.INFO, logger="nmsid"):
        Interlock(InterlockConfig(), BlockingStim()).estop("operator pressed E-stop")
        Interlock(InterlockConfig(), BlockingStim()).trip("force_limit", "45 N > 40 N")
    levels = {r.getMessage(): r.levelno for r in caplog.records
              if r.getMessage().startswith("interlock tripped by")}
    assert levels == {"interlock tripped by estop: operator pressed E-stop": logging.INFO,
                      "interlock tripped by force_limit: 45 N > 40 N": logging.WARNING}


def test_stop_watcher_gives_up_on_a_stuck_switch_read_after_a_second():
    """A switch whose read hangs (a USB device gone mid-call) must not hang the session's
    end: stop_watcher waits one second for the polling thread, then lets it go (a daemon
    thread, ended with the process)."""
    import time  # noqa: PLC0415

    release = threading.Event()
    reading = threading.Event()

    class StuckSwitch:
        def is_pressed(self) -> bool:
            reading.set()
            release.wait(5.0)
            return False

        def close(self) -> None:
            pass

    lock = Interlock(InterlockConfig(), BlockingStim(), estop_input=StuckSwitch())
    lock.start_watcher()
    try:
        assert reading.wait(2.0)
        t0 = time.perf_counter()
        lock.stop_watcher()
        took = time.perf_counter() - t0
    finally:
        release.set()
    assert 0.9 < took < 1.8, took  # 2 s or more: waited too long


def test_the_watcher_does_not_trip_while_the_switch_is_released():
    import time  # noqa: PLC0415

    class Switch:
        pressed = False
        reads = 0

        def is_pressed(self) -> bool:
            self.reads += 1
            return self.pressed

        def close(self) -> None:
            pass

    sw = Switch()
    lock = Interlock(InterlockConfig(), BlockingStim(), estop_input=sw)
    lock.start_watcher()
    try:
        deadline = time.monotonic() + 2.0
        while sw.reads < 5 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert sw.reads >= 5 and not lock.latched
    finally:
        lock.stop_watcher()
