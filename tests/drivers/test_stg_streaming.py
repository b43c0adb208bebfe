"""The STG4002 in streaming mode (drivers/stg_streaming.py; issue 28 item 1) against a fake
built from the McsUsbNet manual's section 6.3 (testing/fakes/fake_stg_streaming.py).

Ceilings checked before EnqueueData, zero net charge per carrier period AFTER the device's
truncation of the lower bits, stop at zero, and every call held to the declared surface.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers import mcs_surface
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.interfaces import CurrentLimitError, HostStreamedStimulator, StimulatorState
from nmsid.drivers.stg_streaming import (
    INT16_FULL,
    RING_S,
    StgStreamingStimulator,
    StreamUnderrunError,
    quantum,
    render_periods,
)

RANGE_NA, RES_NA = 16_000_000, 500


@pytest.fixture
def streaming(fake_mcs):
    fake = load_fake("fake_stg_streaming")
    fake.install(sys.modules)
    stim = StgStreamingStimulator(ceiling_ext_mA=12.0, ceiling_flex_mA=12.0,
                                  ring_samples=5000)
    yield stim, fake, fake_mcs.bench
    stim.disconnect()


def _device(fake):
    return fake.registry()[-1]


def test_it_is_a_host_streamed_stimulator(streaming):
    stim, fake, bench = streaming
    assert isinstance(stim, HostStreamedStimulator)


def test_open_stream_follows_the_manuals_sequence(streaming):
    stim, fake, bench = streaming
    assert stim.open_stream(8.0, 6.0, 1000.0) == pytest.approx(1000.0)
    dev = _device(fake)
    names = [c[0] for c in dev.calls]
    for a, b in (("SetOutputRate", "SetupTrigger"), ("SetCapacity", "SetupTrigger"),
                 ("SetupTrigger", "StartLoop")):
        assert names.index(a) < names.index(b)
    assert dev.continuous is False               # stop, not zero-fill, on an underrun
    assert dev.trigger[0][0] == 0b11 and dev.trigger[4][0] == 50
    assert stim.latency_s == pytest.approx(16_000 / 4 / 50_000)


def test_an_amplitude_above_the_stream_ceiling_sends_nothing(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    with pytest.raises(CurrentLimitError, match="nothing was sent"):
        stim.write_stream(np.array([1.0, 8.01]), np.array([1.0, 1.0]))
    with pytest.raises(CurrentLimitError):
        stim.write_stream(np.array([1.0]), np.array([np.nan]))
    assert not any(c[0] == "EnqueueData" for c in _device(fake).calls)


def test_stream_ceilings_above_the_rig_ceiling_are_refused(streaming):
    stim, fake, bench = streaming
    from nmsid.drivers.errors import DeviceRangeError
    with pytest.raises(DeviceRangeError):
        stim.open_stream(12.5, 6.0, 1000.0)


def test_played_output_nets_zero_per_period_after_truncation_and_stops_at_zero(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    assert stim.stream_space() == 5000 // 50
    amps = np.linspace(0.5, 8.0, 40)
    stim.write_stream(amps, amps * 0.75)
    dev = _device(fake)
    assert not dev.running                       # nothing plays before start()
    stim.start()
    assert dev.running
    bench.sleep(0.02)
    stim.stop_now()
    assert not dev.running and dev.calls[-2][0] == "SendStop"
    for ch, ceiling in ((0, 8.0), (1, 6.0)):
        out = dev.output_at(ch)
        whole = out[: len(out) // 50 * 50].reshape(-1, 50)
        assert len(whole) >= 1 and np.all(whole.sum(axis=1) == 0)
        assert np.abs(out).max() * RANGE_NA / (INT16_FULL - 1) / 1e6 <= ceiling + 1e-9
    assert stim.status().state is StimulatorState.STOPPED
    from nmsid.drivers.errors import DeviceError
    with pytest.raises(DeviceError, match="no open stream"):
        stim.write_stream(np.ones(1), np.ones(1))   # the stream is over


@settings(max_examples=60, deadline=None)
@given(amps=st.lists(st.floats(0.0, 16.0), min_size=1, max_size=8),
       P=st.sampled_from([10, 20, 25, 50, 100]),
       res=st.sampled_from([100, 250, 500, 1000, 2000]))
def test_every_period_nets_zero_after_any_lower_bit_truncation(amps, P, res):
    q = quantum(RANGE_NA, res)
    v = render_periods(np.array(amps), P, RANGE_NA, q).astype(np.int64)
    truncated = v & ~(q - 1)            # what the device keeps (manual 6.3)
    assert np.array_equal(truncated, v)
    assert np.all(truncated.reshape(-1, P).sum(axis=1) == 0)
    peak_nA = np.abs(v).reshape(-1, P).max(axis=1) * RANGE_NA / (INT16_FULL - 1)
    assert np.all(peak_nA <= np.array(amps) * 1e6 + 1e-6)


def test_an_underrun_stops_the_output(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(5, 2.0), np.full(5, 2.0))   # 5 ms of data
    stim.start()
    bench.sleep(0.05)
    dev = _device(fake)
    assert not dev.running and len(dev.output_at(0)) == 250


def test_a_host_that_fell_behind_is_told_the_stg_stopped(streaming):
    # manual 6.3: without continuous mode the STG stops when it runs out of data; the PC
    # queue then stops draining, and the next write says so instead of filling the queue
    # of a stopped device (it used to end, ten updates later, with "room for 0 samples")
    stim, fake, bench = streaming
    stim._now = bench.now
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(80, 2.0), np.full(80, 2.0))   # 80 ms of data
    t0 = bench.now()
    stim.start()
    t1 = bench.now()
    bench.sleep(0.3)   # > 80 ms queued + the STG ring's 80 ms (latency_s) + 20 ms slack
    dev = _device(fake)
    assert not dev.running and len(dev.output_at(0)) == 4000
    before = len(dev.queued.get(0, []))
    t2 = bench.now()
    with pytest.raises(StreamUnderrunError, match=r"fell (\d+) ms behind") as err:
        stim.write_stream(np.full(5, 2.0), np.full(5, 2.0))
    t3 = bench.now()
    assert len(dev.queued.get(0, [])) == before           # nothing was sent
    # behind = elapsed - latency - slack - played, on the clock the driver was given
    behind_ms = float(err.value.args[0].split("fell ")[1].split(" ms")[0])
    lo, hi = (1e3 * (t - 0.08 - 0.02 - 0.08) for t in (t2 - t1, t3 - t0))
    assert lo - 1 <= behind_ms <= hi + 1


def test_a_host_that_keeps_ahead_is_not_called_late(fake_mcs):
    # the negative control of the drain test: one second queued ahead, topped up every
    # 50 ms for 0.3 s, on the bench's clock; the default ring holds RING_S seconds
    fake = load_fake("fake_stg_streaming")
    fake.install(sys.modules)
    stim = StgStreamingStimulator(ceiling_ext_mA=12.0, ceiling_flex_mA=12.0,
                                  clock=fake_mcs.bench.now)
    try:
        assert stim.ring_samples == round(RING_S * 50_000)
        stim.open_stream(8.0, 6.0, 1000.0)
        stim.write_stream(np.full(1000, 2.0), np.full(1000, 2.0))   # 1 s ahead
        stim.start()
        for _ in range(6):
            fake_mcs.bench.sleep(0.05)
            stim.write_stream(np.full(50, 2.0), np.full(50, 2.0))
        assert _device(fake).running
    finally:
        stim.disconnect()


def test_a_failed_stop_tells_the_operator_to_switch_the_stg_off(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(50, 2.0), np.full(50, 2.0))
    stim.start()
    dev = _device(fake)
    dev.hw.unplug()
    stim.stop_now()   # never raises
    assert "SWITCH THE STIMULATOR OFF" in stim.status().error
    assert stim.status().output_active


def test_close_stream_is_idempotent_and_ends_at_zero(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(10, 2.0), np.full(10, 2.0))
    stim.start()
    t0 = time.monotonic()
    stim.close_stream()
    stim.close_stream()
    assert time.monotonic() - t0 < 2.0
    dev = _device(fake)
    out = dev.output_at(0)
    assert not dev.running and (len(out) == 0 or out[-1] == 0)


def test_every_streaming_call_is_in_the_declared_surface(streaming):
    from nmsid.testing.fakes import fake_dotnet as fd
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.stream_space()
    stim.write_stream(np.full(3, 2.0), np.full(3, 2.0))
    stim.start()
    stim.stop_now()
    stim.disconnect()

    def net(a):
        if isinstance(a, fd.NetArray):
            return f"System.{a.element_type.NAME}[]"
        if isinstance(a, fd._NetInt):
            return f"System.{type(a).NAME}"
        return "Mcs.Usb.CMcsUsbListEntryNet"
    calls = {(c[0], tuple(net(a) for a in c[1:])) for c in _device(fake).calls}
    off = [c for c in calls if not mcs_surface.has_overload("CStg200xStreamingNet", *c)]
    assert off == []
    offered = {n for n in vars(fake.CStg200xStreamingNet) if n[:1].isupper()}
    assert offered - mcs_surface.members_of("CStg200xStreamingNet") == set()


# -- the STG's own memory (issue 37 item 4; McsUsbNet manual 6.3, XML GetFramesBuffered) --
def test_the_fake_stg_started_before_its_memory_holds_data_runs_dry_at_once(streaming):
    # the manual's example waits after StartLoop ("Give StartLoop some time"); with
    # continuous mode disabled an STG started with nothing in its memory stops at once
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(40, 2.0), np.full(40, 2.0))
    dev = _device(fake)
    dev.StartLoop()                                # (again: this instant, whatever the
    dev.SendStart(fake.UInt32(1))                  # host's speed) and at once SendStart
    bench.sleep(0.1)
    assert not dev.running and len(dev.output_at(0)) == 0


def test_start_waits_until_the_stg_holds_the_queued_data(streaming):
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(40, 2.0), np.full(40, 2.0))     # 40 ms: 2000 frames
    stim.start()
    dev = _device(fake)
    names = [c[0] for c in dev.calls]
    assert "GetFramesBuffered" in names[:names.index("SendStart")]
    # the whole queue plays (then the STG runs dry, as asked, manual 6.3)
    t0 = time.monotonic()
    while dev.running and time.monotonic() - t0 < 10.0:     # generous: a loaded host
        bench.sleep(0.01)
    assert len(dev.output_at(0)) == 2000


def test_start_refuses_when_the_data_never_reaches_the_stg(streaming, monkeypatch):
    from nmsid.drivers import stg_streaming
    from nmsid.drivers.errors import DeviceError
    stim, fake, bench = streaming
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(10, 2.0), np.full(10, 2.0))
    dev = _device(fake)
    dev.transfer_delay_s = 1e9                               # a transfer that never begins
    monkeypatch.setattr(stg_streaming, "PRIME_TIMEOUT_S", 0.05)
    with pytest.raises(DeviceError, match="GetFramesBuffered"):
        stim.start()
    assert not dev.running and "SendStart" not in [c[0] for c in dev.calls]


# -- an underrun after the host's last write: found at close (McsUsbNet manual 6.3) --------
class _SteppedClock:
    """Device and driver time that move only when the test says (no machine speed)."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def stepped(fake_mcs):
    fake = load_fake("fake_stg_streaming")
    clock = _SteppedClock()
    fake_mcs(hardware=[fake_mcs.module.FakeStgHardware(clock=clock)])
    fake.install(sys.modules)
    stim = StgStreamingStimulator(ceiling_ext_mA=12.0, ceiling_flex_mA=12.0,
                                  ring_samples=20_000, clock=clock)
    yield stim, fake, clock
    stim.disconnect()


def test_a_stream_that_ran_dry_before_its_last_write_played_is_reported_at_close(stepped):
    # the STG plays 40 ms and runs dry (continuous mode disabled: it stops, manual 6.3);
    # the last 60 ms are written 10 ms later, within the write's drain allowance (latency
    # 80 ms + 20 ms), so no write says so: only the close can
    stim, fake, clock = stepped
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(40, 2.0), np.full(40, 2.0))
    clock.t = 0.05                           # the data are in the STG's memory
    stim.start()
    clock.t = 0.10                           # it ran dry at 0.09 (0.05 + 40 ms)
    stim.write_stream(np.full(60, 2.0), np.full(60, 2.0))     # no StreamUnderrunError
    dev = _device(fake)
    assert not dev.running and dev.stop_t == pytest.approx(0.09)
    clock.t = 0.50
    said = stim.close_stream()
    assert "ran out of streamed data" in said and "manual 6.3" in said
    assert "0.040 s into the stream of 0.100 s" in said and "last 0.060 s" in said
    assert stim.close_stream() == said       # idempotent: the hook asks again
    assert not dev.running and dev.calls[-2][0] == "SendStop"
    assert len(dev.output_at(0)) == 2000     # what played: the first 40 ms only
    later = dev.stop_t + np.linspace(0.0, 0.5, 50)
    assert not dev.current_at(0, later).any() and not dev.current_at(1, later).any()


def test_a_stream_whose_data_stopped_reaching_the_stg_is_reported_at_close(stepped,
                                                                          monkeypatch):
    # everything written before the start; frames from 120 ms on never reach the STG's
    # memory (a stalled transfer): it stops there with no write left to notice
    stim, fake, clock = stepped
    cut = 6000
    real = fake.CStg200xStreamingNet._arrival

    def starved(self, ch, limit=None):
        arr = real(self, ch, limit)
        return np.where(self._head + np.arange(len(arr)) >= cut, np.inf, arr)
    monkeypatch.setattr(fake.CStg200xStreamingNet, "_arrival", starved)
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(200, 2.0), np.full(200, 2.0))    # 200 ms, 10 000 frames
    clock.t = 0.05
    stim.start()
    clock.t = 0.40
    said = stim.close_stream()
    assert "0.120 s into the stream of 0.200 s" in said and "last 0.080 s" in said
    dev = _device(fake)
    assert not dev.running and len(dev.output_at(0)) == cut


def test_a_stream_that_played_out_is_not_called_an_underrun(stepped):
    # the negative control: the STG ran out of data at the stream's end (its ordinary end,
    # manual 6.3), before the close's zero period
    stim, fake, clock = stepped
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(100, 2.0), np.full(100, 2.0))
    clock.t = 0.05
    stim.start()
    clock.t = 0.30
    assert stim.close_stream() == ""
    dev = _device(fake)
    assert len(dev.output_at(0)) == 5000 and not dev.running


def test_a_stream_closed_while_it_plays_plays_out_and_is_not_an_underrun(streaming):
    # closed with 100 ms still queued (an operator's abort): the close waits on the
    # device's clock until it played, whatever the host's speed
    stim, fake, bench = streaming
    stim._now = bench.now
    stim.open_stream(8.0, 6.0, 1000.0)
    stim.write_stream(np.full(100, 2.0), np.full(100, 2.0))
    stim.start()
    assert stim.close_stream() == ""
    dev = _device(fake)
    out = dev.output_at(0)
    assert len(out) >= 5000 and out[-1] == 0 and not dev.running


def test_the_download_driver_hands_on_the_close_report(fake_mcs):
    from nmsid.drivers.stg_streaming import Stg4002WithStreaming
    fake = load_fake("fake_stg_streaming")
    clock = _SteppedClock()
    fake_mcs(hardware=[fake_mcs.module.FakeStgHardware(clock=clock)])
    fake.install(sys.modules)
    common = {"ceiling_ext_mA": 12.0, "ceiling_flex_mA": 12.0}
    stim = Stg4002WithStreaming(
        streaming=StgStreamingStimulator(ring_samples=20_000, clock=clock, **common),
        clock=clock, **common)
    try:
        stim.open_stream(8.0, 6.0, 1000.0)
        stim.write_stream(np.full(40, 2.0), np.full(40, 2.0))
        clock.t = 0.05
        stim.start()
        clock.t = 0.10
        stim.write_stream(np.full(60, 2.0), np.full(60, 2.0))
        clock.t = 0.50
        stim.stop_after_period()            # run_block's ordinary end closes the stream
        said = stim.close_stream()          # then the stream's hook asks
        assert "0.040 s into the stream" in said and not stim.streaming_open
    finally:
        stim.disconnect()
