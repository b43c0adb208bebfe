"""The simulated devices: interface behaviour, safety, clocks and state across chunks."""

import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers.errors import DeviceRangeError
from nmsid.drivers.interfaces import CheckedWaveform, StimulatorState
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import currents_for, run_waveform, waveform
from nmsid.sim_backends.errors import DeviceStateError
from nmsid.sim_backends.faults import Fault, FaultKind
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.sensor import SensorModel
from nmsid.sim_backends.simulation import ParticipantSimulator

FS = 2000.0


def _step_trial(p, n_s=1.0, sE=0.6, level=0.9):
    rE = np.full(int(n_s * FS), level)
    return currents_for(p.calibration, sE, rE)


def _offline(p, I_e, I_f, n_stop=None, n_total=None):
    """Reference: the participant simulated in one block, output zero from n_stop."""
    n_total = n_total or I_e.size
    e = np.zeros(n_total)
    f = np.zeros(n_total)
    m = min(I_e.size, n_total if n_stop is None else n_stop)
    q = lambda x: np.minimum(np.floor(x * 1000 + 1e-6) / 1000, x)  # noqa: E731
    e[:m], f[:m] = q(I_e[:m]), q(I_f[:m])
    return ParticipantSimulator(p, FS).simulate(e, f).force_N


def test_stop_now_from_another_thread_zeroes_output_in_real_time():
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, realtime=True)
    rig.stimulator.connect()
    I_e, I_f = _step_trial(p, n_s=0.8)
    timer = threading.Timer(0.3, rig.stimulator.stop_now)
    stim, acq = rig.stimulator, rig.acquisition
    stim.load(waveform(I_e, I_f))
    stim.arm()
    acq.start(I_e.size, triggered=True)
    stim.start()
    timer.start()
    chunks = []
    t_wall = time.monotonic()
    while sum(c.n for c in chunks) < I_e.size and time.monotonic() - t_wall < 5:
        c = acq.read(0.05)
        if c is not None:
            chunks.append(c)
    acq.stop()
    timer.join()
    force = np.concatenate([c.force_N for c in chunks])
    sync = np.concatenate([c.sync for c in chunks])
    zero = rig.output_zero_events
    assert len(zero) == 1 and zero[0].reason == "stop_now"
    n_stop = zero[0].sample_index
    # when the other thread asked (0.3 s after the trigger; a loaded machine may be late)
    assert 0.28 * FS <= n_stop <= 0.75 * FS
    assert np.all(sync[n_stop:] == 0) and np.all(sync[:n_stop] > 0)
    # force decays from the state it had, as if the currents had stopped at n_stop
    assert np.max(np.abs(force - _offline(p, I_e, I_f, n_stop))) < 1e-9
    assert stim.status().state is StimulatorState.STOPPED
    assert not stim.status().output_active
    stim.stop_now()                                          # idempotent
    stim.disconnect()
    stim.stop_now()                                          # never raises
    assert len(rig.output_zero_events) == 1


def test_estop_mid_trial_gives_a_decaying_force_with_continuous_state():
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, faults=[Fault(FaultKind.ESTOP, trial=0, at_s=0.45)])
    rig.stimulator.connect()
    I_e, I_f = _step_trial(p, n_s=1.5)

    def watch(r, chunk):
        if r.estop.is_pressed():
            r.stimulator.stop_now()
        return False
    force, chunks = run_waveform(rig, waveform(I_e, I_f), on_chunk=watch)
    n_stop = rig.output_zero_events[0].sample_index
    assert n_stop == 1000                      # first chunk boundary after 0.45 s (0.1 s chunks)
    assert rig.faults.fired[0].fault.kind is FaultKind.ESTOP
    assert rig.faults.fired[0].scheduled_clock_s == pytest.approx(0.45)
    assert np.max(np.abs(force - _offline(p, I_e, I_f, n_stop))) < 1e-9
    tail = np.abs(force[-200:])
    assert tail.max() < 0.01 * np.abs(force[:n_stop]).max()   # decayed


def test_fast_and_real_time_clocks_give_identical_samples():
    p = default_participant(seed=7)              # noise, mains, drift, offset all on
    I_e, I_f = _step_trial(p, n_s=1.3)           # longer than a real-time block (1 s)
    out = []
    for realtime in (False, True):
        rig = make_sim_rig(p, realtime=realtime)
        rig.stimulator.connect()
        force, chunks = run_waveform(rig, waveform(I_e, I_f))
        out.append((force, np.concatenate([c.wrench for c in chunks]), len(chunks)))
    assert out[0][2] < out[1][2]                 # the chunking differs ...
    assert np.array_equal(out[0][0], out[1][0])  # ... the samples do not
    assert np.array_equal(out[0][1], out[1][1])


def test_real_time_reads_block_until_samples_are_due():
    rig = make_sim_rig(default_participant(), realtime=True)
    rig.stimulator.connect()
    p = rig.participant
    I_e, I_f = _step_trial(p, n_s=0.3)
    t0 = time.monotonic()
    force, chunks = run_waveform(rig, waveform(I_e, I_f))
    elapsed = time.monotonic() - t0
    assert 0.28 <= elapsed < 3.0
    assert all(c.n <= 40 for c in chunks)        # 20 ms chunks in real time


def test_chunking_and_back_to_back_trials_do_not_change_the_samples():
    p = default_participant(seed=3)
    I_e, I_f = _step_trial(p, n_s=1.0)
    ref_rig = make_sim_rig(p, connect=True)
    both = np.concatenate([I_e, I_e]), np.concatenate([I_f, I_f])
    ref, _ = run_waveform(ref_rig, waveform(*both))
    for chunk_s in (0.1, 0.0135):
        rig = make_sim_rig(p, chunk_s=chunk_s, connect=True)
        a, _ = run_waveform(rig, waveform(I_e, I_f))
        b, _ = run_waveform(rig, waveform(I_e, I_f))      # state carries over, no rest
        assert np.array_equal(np.concatenate([a, b]), ref)


def test_load_validation_and_state_errors():
    rig = make_sim_rig()
    stim = rig.stimulator
    n = 200
    ok = waveform(np.full(n, 3.0), np.full(n, 3.0))
    with pytest.raises(DeviceStateError, match="connect"):
        stim.load(ok)
    stim.connect()
    with pytest.raises(TypeError, match="CheckedWaveform"):
        stim.load(np.zeros(n))
    too_high = CheckedWaveform(np.full(n, 17.0), np.zeros(n), FS, 1000.0, 30.0, 30.0)
    with pytest.raises(DeviceRangeError, match="16 mA"):
        stim.load(too_high)
    with pytest.raises(DeviceStateError, match="arm"):
        stim.start()
    stim.load(ok)
    stim.arm()
    rig.acquisition.start(n)
    stim.start()
    assert stim.status().output_active
    with pytest.raises(DeviceStateError, match="running"):
        stim.load(ok)
    with pytest.raises(DeviceStateError, match="stop"):
        rig.acquisition.start(n)
    rig.close()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.0, 16.0, allow_subnormal=False), min_size=1, max_size=50),
       st.floats(0.0, 16.0))
def test_delivered_current_is_never_above_the_request_or_ceiling(levels, ceiling):
    arr = np.minimum(np.asarray(levels), ceiling)
    rig = make_sim_rig(participant=default_participant(sensor=SensorModel.ideal()),
                       connect=True)
    wf = CheckedWaveform(arr, arr[::-1].copy(), FS, 1000.0, ceiling, ceiling)
    run_waveform(rig, wf)
    assert max(rig.max_delivered_mA) <= ceiling
    assert max(rig.max_sent_mA) <= ceiling
    assert rig.max_sent_mA[0] >= arr.max() - 0.001


def test_acquisition_takes_a_trigger_fired_before_it_started_and_free_runs():
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, connect=True)
    I_e, I_f = _step_trial(p, n_s=0.5)
    rig.stimulator.load(waveform(I_e, I_f))
    rig.stimulator.arm()
    rig.stimulator.start()                       # trigger first ...
    rig.acquisition.start(I_e.size)              # ... then a triggered acquisition
    c = rig.acquisition.read(0.05)
    assert c.start_index == 0
    rig.acquisition.stop()
    rig.acquisition.start(300, triggered=False)  # free-running: starts now
    c = rig.acquisition.read(0.05)
    assert c.start_index == 0 and c.n == 200
    assert rig.acquisition.read(1.0).n == 100
    assert rig.acquisition.read(0.05) is None     # all 300 delivered


def test_concurrent_stop_now_calls_while_reading_on_the_fast_clock():
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, connect=True)
    I_e, I_f = _step_trial(p, n_s=20.0)
    errors = []
    started = threading.Event()
    first_stop = threading.Event()

    def stopper():
        started.wait()
        try:
            for _ in range(50):
                rig.stimulator.stop_now()
                first_stop.set()
                time.sleep(0)
        except Exception as exc:  # stop_now must never raise
            errors.append(exc)

    def on_chunk(r, c):
        started.set()
        # the reader goes on once a stop has been asked: on a fast clock a busy host could
        # otherwise finish the 20 s trial before any stopper thread ran (no stop at all);
        # the other calls still race the reads
        first_stop.wait(10.0)
        return False
    threads = [threading.Thread(target=stopper) for _ in range(3)]
    for th in threads:
        th.start()
    force, chunks = run_waveform(rig, waveform(I_e, I_f), on_chunk=on_chunk)
    for th in threads:
        th.join()
    assert not errors
    zero = rig.output_zero_events
    assert len(zero) == 1
    sync = np.concatenate([c.sync for c in chunks])
    n_stop = zero[0].sample_index
    assert np.all(sync[n_stop:] == 0) and np.all(sync[:n_stop] > 0)
    assert np.max(np.abs(force - _offline(p, I_e, I_f, n_stop))) < 1e-9


@settings(max_examples=25, deadline=None)
@given(st.sampled_from(list(FaultKind)), st.floats(0.0, 0.9), st.integers(0, 1))
def test_after_any_fault_and_a_stop_the_output_is_zero(kind, at_s, trial):
    """An engine-like loop stops on any fault it can see; from then on nothing is output."""
    from nmsid.sim_backends.errors import SensorDisconnected, StimulatorFault
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, faults=[Fault(kind, trial=trial, at_s=at_s, amplitude_N=80.0)],
                       connect=True)
    I_e, I_f = _step_trial(p, n_s=1.0)
    stops = []

    def watch(r, c):
        st_ = r.stimulator.status()
        seen = (c is None or c.flags.any or np.abs(c.force_N).max() > 50
                or r.estop.is_pressed() or st_.state is StimulatorState.ERROR)
        if seen and not stops:
            stops.append(r.world.sample_at(r.clock.monotonic_s()))   # "now" on the rig
            r.stimulator.stop_now()
        return False
    for _ in range(2):
        try:
            run_waveform(rig, waveform(I_e, I_f), on_chunk=watch, max_reads=60)
        except (StimulatorFault, SensorDisconnected):  # refused at start: nothing output
            stops.append(-1)
            break
    status = rig.stimulator.status()
    assert not status.output_active
    rig.clock.sleep(0.5)
    assert not rig.world.output_active_at(rig.clock.monotonic_s())
    for rec in rig.run_records:
        if stops and stops[0] >= 0 and rec.N_trigger < stops[0] < rec.N_trigger + rec.n_planned:
            assert rec.N_end is not None and rec.N_end <= stops[0]


def test_configure_rate_before_first_use_only():
    rig = make_sim_rig(default_participant(sensor=SensorModel.ideal()), connect=True)
    assert rig.acquisition.configure(1000.0) == 1000.0
    p = rig.participant
    I_e, I_f = currents_for(p.calibration, 0.6, np.full(1000, 0.9))
    force, chunks = run_waveform(rig, waveform(I_e, I_f, fs_Hz=1000.0))
    assert chunks[0].n == 100 and not np.isnan(force).any()     # 0.1 s chunks at 1 kHz
    assert rig.acquisition.configure(1000.0) == 1000.0            # same rate: fine
    with pytest.raises(DeviceStateError, match="1000 Hz"):
        rig.acquisition.configure(2000.0)


def test_a_stop_is_recorded_even_if_no_device_call_follows():
    p = default_participant(sensor=SensorModel.ideal())
    rig = make_sim_rig(p, connect=True)
    I_e, I_f = _step_trial(p, n_s=1.0)
    rig.stimulator.load(waveform(I_e, I_f))
    rig.stimulator.arm()
    rig.acquisition.start(I_e.size)
    rig.stimulator.start()
    rig.acquisition.read(0.05)
    rig.stimulator.stop_now()
    ev = rig.output_zero_events
    assert len(ev) == 1 and ev[0].sample_index == 200
