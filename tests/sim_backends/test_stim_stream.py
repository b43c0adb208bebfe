"""Host-streamed stimulation on the simulated stimulator (HostStreamedStimulator)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers.interfaces import CurrentLimitError, HostStreamedStimulator
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.sensor import SensorModel
from nmsid.sim_backends.stim_stream import stream_rate


def _rig():
    rig = make_sim_rig(default_participant(sensor=SensorModel.ideal()))
    rig.stimulator.connect()
    return rig


def _stream(rig, ceil=(8.0, 7.0), update_Hz=200.0, n_updates=100, amps=None, prefill=1):
    """Open, prefill, start, then one update per chunk read; the delivered envelope."""
    stim, acq = rig.stimulator, rig.acquisition
    rate = stim.open_stream(ceil[0], ceil[1], update_Hz)
    spu = stim.stream.samples_per_update
    n = n_updates * spu
    acq.start(n, triggered=True)
    amps = amps if amps is not None else (lambda i, f: (5.0, 4.0))
    for i in range(prefill):
        stim.write_stream(*(np.array([a]) for a in amps(i, None)))
    stim.arm()
    stim.start()
    got, i = 0, prefill
    forces = []
    while got < n:
        ch = acq.read(0.05)
        if ch is None or not ch.n:
            continue
        got = ch.start_index + ch.n
        forces.append(ch.force_N)
        if i < n_updates:
            e, f = amps(i, ch.force_N[-1])
            stim.write_stream(np.array([e]), np.array([f]))
            i += 1
    stim.close_stream()
    acq.stop()
    I_e, I_f, _ = rig.world.output(rig.run_records[-1].N_trigger,
                                   rig.run_records[-1].N_trigger + n)
    return rate, spu, np.concatenate(forces), I_e, I_f


def test_sim_stimulator_has_the_capability():
    assert isinstance(_rig().stimulator, HostStreamedStimulator)


@given(update_Hz=st.floats(1.0, 2000.0), carrier_Hz=st.sampled_from([250.0, 500.0, 1000.0]))
def test_every_update_lasts_whole_carrier_periods_and_samples(update_Hz, carrier_Hz):
    rate, spu = stream_rate(update_Hz, carrier_Hz, 2000.0)
    periods = carrier_Hz / rate
    assert abs(periods - round(periods)) < 1e-9 and round(periods) >= 1
    assert spu == pytest.approx(2000.0 / rate) and spu >= 1


def test_charge_balanced_per_carrier_period():
    rig = _rig()
    rng = np.random.default_rng(3)
    vals = rng.uniform(0, 7.0, size=(60, 2))
    _rate, _spu, _, I_e, _ = _stream(rig, n_updates=60, amps=lambda i, f: tuple(vals[i]))
    # render the sine carrier at the device's output rate from the delivered envelope
    out_Hz, carrier = 50_000.0, rig.stimulator.last_stream.carrier_Hz
    k = np.arange(int(I_e.size * out_Hz / 2000.0))
    env = I_e[np.floor(k * 2000.0 / out_Hz).astype(int)]
    wave = env * np.sin(2 * np.pi * carrier * k / out_Hz)
    per = int(out_Hz / carrier)
    charge = wave[: wave.size // per * per].reshape(-1, per).sum(axis=1) / out_Hz
    peak_charge = env.max() / out_Hz * per
    assert np.abs(charge).max() < 1e-9 * peak_charge
    # and the envelope really changed (not a constant that balances trivially)
    assert np.unique(np.round(I_e, 3)).size > 30


def test_closed_loop_update_acts_one_update_after_the_force_sample():
    rig = _rig()
    seen = []

    def amps(i, f):
        seen.append(i)
        return (6.0, 4.0) if i < 20 else (3.0, 2.5)

    _rate, spu, _force, I_e, _I_f = _stream(rig, n_updates=40, amps=amps)
    # update i (written after reading chunk i-1) starts at sample i*spu
    assert np.all(I_e[20 * spu:] == 3.0) and np.all(I_e[: 20 * spu] == 6.0)
    assert rig.stimulator.last_stream.underrun_updates == 0


def test_write_above_the_ceiling_is_refused_and_nothing_queued():
    rig = _rig()
    stim = rig.stimulator
    stim.open_stream(5.0, 5.0, 200.0)
    stim.write_stream(np.array([4.0]), np.array([4.0]))
    with pytest.raises(CurrentLimitError, match="exceeds the stream's ceiling"):
        stim.write_stream(np.array([1.0, 5.0001]), np.array([1.0, 1.0]))
    with pytest.raises(CurrentLimitError, match="non-finite"):
        stim.write_stream(np.array([math.nan]), np.array([1.0]))
    with pytest.raises(CurrentLimitError, match="negative"):
        stim.write_stream(np.array([1.0]), np.array([-0.1]))
    assert stim.stream.written == 1
    stim.close_stream()


def test_device_range_caps_the_stream_ceiling():
    rig = _rig()
    stim = rig.stimulator
    stim.open_stream(100.0, 100.0, 200.0)
    assert stim.stream.ceiling_ext_mA == 16.0
    with pytest.raises(CurrentLimitError):
        stim.write_stream(np.array([16.5]), np.array([1.0]))
    stim.close_stream()


@settings(max_examples=40, deadline=None)
@given(requests=st.lists(st.tuples(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.floats(allow_nan=True, allow_infinity=True, width=32)), min_size=1, max_size=12),
    ceil_e=st.floats(0.0, 16.0), ceil_f=st.floats(0.0, 16.0))
def test_no_streamed_sample_above_its_ceiling_whatever_is_asked(requests, ceil_e, ceil_f):
    rig = make_sim_rig(default_participant(sensor=SensorModel.ideal()))
    rig.stimulator.connect()
    stim, acq = rig.stimulator, rig.acquisition
    stim.open_stream(ceil_e, ceil_f, 500.0)
    spu = stim.stream.samples_per_update
    n = len(requests) * spu
    acq.start(n, triggered=True)
    stim.arm()
    stim.start()
    for e, f in requests:
        try:
            stim.write_stream(np.array([e]), np.array([f]))
        except CurrentLimitError:
            pass   # refused whole: nothing queued
        acq.read(0.05)
    stim.close_stream()
    acq.stop()
    rec = rig.run_records[-1]
    I_e, I_f, _ = rig.world.output(rec.N_trigger, rec.N_trigger + n)
    assert I_e.max(initial=0) <= ceil_e and I_f.max(initial=0) <= ceil_f
    assert rig.max_delivered_mA[0] <= ceil_e and rig.max_delivered_mA[1] <= ceil_f


def test_stop_now_ends_a_stream_with_output_zero_even_if_writes_go_on():
    rig = _rig()
    stim, acq = rig.stimulator, rig.acquisition
    stim.open_stream(8.0, 8.0, 200.0)
    spu = stim.stream.samples_per_update
    acq.start(40 * spu, triggered=True)
    stim.write_stream(np.array([5.0]), np.array([4.0]))
    stim.arm()
    stim.start()
    for i in range(40):
        acq.read(0.05)
        if i == 10:
            stim.stop_now()
        stim.write_stream(np.array([5.0]), np.array([4.0]))
    rec = rig.run_records[-1]
    I_e, I_f, _ = rig.world.output(rec.N_trigger, rec.N_trigger + 40 * spu)
    assert I_e[: 10 * spu].min() == 5.0
    assert not I_e[12 * spu:].any() and not I_f[12 * spu:].any()
    assert rig.output_zero_events and rig.output_zero_events[0].reason == "stop_now"
    stim.close_stream()


def test_a_late_host_underruns_to_zero_output():
    rig = _rig()
    stim, acq = rig.stimulator, rig.acquisition
    stim.open_stream(8.0, 8.0, 200.0)
    spu = stim.stream.samples_per_update
    acq.start(20 * spu, triggered=True)
    stim.write_stream(np.array([5.0]), np.array([4.0]))
    stim.arm()
    stim.start()
    for _ in range(5):
        acq.read(0.05)    # reads without writing: updates 1..4 are missed
    stim.write_stream(np.array([5.0]), np.array([4.0]))
    assert stim.stream.underrun_updates == 4
    stim.close_stream()
