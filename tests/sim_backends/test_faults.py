"""Fault-script events fire when scheduled and do what they say."""

import numpy as np
import pytest

from nmsid.drivers.interfaces import StimulatorState
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.direct_drive import currents_for, run_waveform, waveform
from nmsid.sim_backends.errors import SimConfigError, StimulatorDisconnected, StimulatorFault
from nmsid.sim_backends.faults import Fault, FaultKind, FaultScript
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.sensor import SensorModel

FS = 2000.0


def _p():
    return default_participant(sensor=SensorModel.ideal())


def _trial_wf(p, n_s=2.0, sE=0.6, level=0.8):
    I_e, I_f = currents_for(p.calibration, sE, np.full(int(n_s * FS), level))
    return waveform(I_e, I_f)


def _single_muscle_wf(n_s=0.5, mA=3.0):
    n = int(n_s * FS)
    return waveform(np.full(n, mA), np.zeros(n))


def _reference(p, wf):
    rig = make_sim_rig(p, connect=True)
    force, _ = run_waveform(rig, wf)
    return force


def test_stall_delivers_nothing_for_its_duration_then_the_backlog():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.SENSOR_STALL, trial=0, at_s=0.75,
                                        duration_s=0.3)], connect=True)
    wf = _trial_wf(p)
    stim, acq = rig.stimulator, rig.acquisition
    stim.load(wf)
    stim.arm()
    acq.start(wf.n_samples)
    stim.start()
    log = []
    while True:
        c = acq.read(0.05)
        log.append((rig.clock.monotonic_s(), None if c is None else c.start_index))
        if c is not None and c.start_index + c.n >= wf.n_samples:
            break
    starts = [k for _, k in log if k is not None]
    assert 1500 in starts and all(k % 100 == 0 for k in starts)   # cut at the stall sample
    silent = [t for t, k in log if k is None]
    assert silent and min(silent) >= 0.75 and max(silent) <= 1.05 + 1e-9
    assert len(silent) == 6                                    # 0.3 s of 50 ms reads
    assert starts == sorted(starts) and starts[0] == 0         # nothing lost
    fired = rig.faults.fired[0]
    assert fired.fault.kind is FaultKind.SENSOR_STALL and fired.start_index == 1500


def test_stall_without_duration_lasts_until_the_acquisition_restarts():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.SENSOR_STALL, run=0, at_s=0.2)],
                       connect=True)
    force, chunks = run_waveform(rig, _trial_wf(p, n_s=1.0), max_reads=40)
    assert chunks[-1].start_index + chunks[-1].n == 400 and np.isnan(force[400:]).all()
    force2, _ = run_waveform(rig, _trial_wf(p, n_s=0.5))
    assert not np.isnan(force2).any()


@pytest.mark.parametrize("kind,flag", [(FaultKind.OVER_RANGE, "over_range"),
                                       (FaultKind.SENSOR_FAULT, "sensor_fault"),
                                       (FaultKind.OVERRUN, "overrun")])
def test_flags_appear_on_the_chunk_at_the_scheduled_sample(kind, flag):
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(kind, trial=0, at_s=0.5123)], connect=True)
    _, chunks = run_waveform(rig, _trial_wf(p, n_s=1.0))
    flagged = [c.start_index for c in chunks if getattr(c.flags, flag)]
    assert flagged == [1025] and all(not c.flags.any for c in chunks if c.start_index != 1025)
    assert "simulated" in [c for c in chunks if c.start_index == 1025][0].flags.detail


def test_overrun_loses_samples():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.OVERRUN, trial=0, at_s=0.5, lost_s=0.01)],
                       connect=True)
    wf = _trial_wf(p, n_s=1.0)
    force, chunks = run_waveform(rig, wf)
    flagged = [c for c in chunks if c.flags.overrun]
    assert [c.start_index for c in flagged] == [1020]
    assert np.isnan(force[1000:1020]).all() and not np.isnan(force[1020:]).any()
    ref = _reference(p, wf)
    assert np.allclose(force[1020:], ref[1020:], atol=1e-12)    # the participant ran on


def test_force_spike_adds_its_amplitude_at_its_time():
    p = _p()
    wf = _trial_wf(p, n_s=1.0)
    rig = make_sim_rig(p, faults=[Fault(FaultKind.FORCE_SPIKE, trial=0, at_s=0.75,
                                        amplitude_N=30.0, duration_s=0.002)], connect=True)
    force, _ = run_waveform(rig, wf)
    diff = force - _reference(p, wf)
    assert np.allclose(diff[1500:1504], 30.0) and np.abs(np.delete(diff, range(1500, 1504))
                                                          ).max() < 1e-12


def test_ramp_steps_are_runs_not_trials():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.FORCE_SPIKE, trial=0, at_s=0.1,
                                        amplitude_N=20.0)], connect=True)
    ramp, _ = run_waveform(rig, _single_muscle_wf())
    assert np.abs(ramp).max() < 10
    trial, _ = run_waveform(rig, _trial_wf(p, n_s=0.5))
    assert trial[200] > 15
    assert rig.faults.fired[0].run_index == 1


def test_stimulator_disconnect_mid_trial():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.STIM_DISCONNECT, trial=0, at_s=0.6)],
                       connect=True)
    wf = _trial_wf(p, n_s=1.5)
    status = []
    force, chunks = run_waveform(
        rig, wf, on_chunk=lambda r, c: status.append(r.stimulator.status()) and False)
    sync = np.concatenate([c.sync for c in chunks])
    assert np.all(sync[1200:] == 0) and np.all(sync[:1200] > 0)
    assert status[4].state is StimulatorState.RUNNING
    assert status[6].state is StimulatorState.ERROR and "disconnected" in status[6].error
    ev = rig.output_zero_events
    assert len(ev) == 1 and ev[0].reason == "stim_disconnect" and ev[0].sample_index == 1200
    with pytest.raises(StimulatorDisconnected):
        rig.stimulator.load(wf)
    with pytest.raises(ConnectionError):
        rig.stimulator.arm()
    rig.stimulator.connect()                    # back: usable again
    force2, _ = run_waveform(rig, _trial_wf(p, n_s=0.5))
    assert rig.stimulator.status().state is StimulatorState.STOPPED


def test_stimulator_error_at_the_start_of_a_trial_refuses_the_load():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.STIM_ERROR, trial=1, detail="overheat")],
                       connect=True)
    run_waveform(rig, _single_muscle_wf())
    run_waveform(rig, _trial_wf(p, n_s=0.3))
    with pytest.raises(StimulatorFault, match="overheat"):
        rig.stimulator.load(_trial_wf(p, n_s=0.3))
    assert rig.stimulator.status().state is StimulatorState.ERROR
    assert rig.max_sent_mA[0] > 0 and len(rig.run_records) == 2


def test_estop_at_session_time():
    p = _p()
    rig = make_sim_rig(p, faults=FaultScript([Fault(FaultKind.ESTOP, session_s=3.0)]))
    rig.clock.sleep(2.999)
    assert not rig.estop.is_pressed()
    rig.clock.sleep(0.002)
    assert rig.estop.is_pressed() and rig.estop.pressed_at_s == pytest.approx(3.0)
    rig.clock.sleep(10)
    assert rig.estop.is_pressed()               # latched
    rig.estop.release()
    assert not rig.estop.is_pressed()
    rig.estop.close()
    assert rig.estop.is_pressed()               # unreadable switch reads as pressed


def test_session_time_sensor_fault_lands_on_its_sample():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.OVER_RANGE, session_s=1.3)], connect=True)
    rig.clock.sleep(1.0)
    _, chunks = run_waveform(rig, _trial_wf(p, n_s=1.0))   # trigger at 1.0 s
    assert [c.start_index for c in chunks if c.flags.over_range] == [600]


def test_fault_validation():
    with pytest.raises(SimConfigError, match="exactly one"):
        Fault(FaultKind.ESTOP)
    with pytest.raises(SimConfigError, match="exactly one"):
        Fault(FaultKind.ESTOP, trial=1, session_s=2.0)
    with pytest.raises(SimConfigError, match="valid"):
        Fault("meteor", trial=0)
    with pytest.raises(SimConfigError, match="duration_s"):
        Fault(FaultKind.SENSOR_STALL, trial=0, duration_s=-1)
    assert Fault("estop", trial=0).kind is FaultKind.ESTOP


def test_faults_can_be_added_after_the_rig_was_made():
    p = _p()
    rig = make_sim_rig(p, connect=True)
    run_waveform(rig, _trial_wf(p, n_s=0.5))
    rig.add_fault(Fault(FaultKind.ESTOP, session_s=rig.clock.monotonic_s() + 0.2))
    rig.add_fault(Fault(FaultKind.FORCE_SPIKE, trial=1, at_s=0.1, amplitude_N=25.0))
    assert not rig.estop.is_pressed()
    force, _ = run_waveform(rig, _trial_wf(p, n_s=0.5))
    assert rig.estop.is_pressed() and force[200] > 20


def test_dropout_loses_the_stalled_samples_and_flags_the_next_chunk():
    p = _p()
    rig = make_sim_rig(p, faults=[Fault(FaultKind.SENSOR_STALL, trial=0, at_s=0.5,
                                        duration_s=0.2, lost_s=0.2)], connect=True)
    wf = _trial_wf(p, n_s=1.5)
    force, chunks = run_waveform(rig, wf)
    flagged = [c for c in chunks if c.flags.overrun]
    assert [c.start_index for c in flagged] == [1400] and "dropout" in flagged[0].flags.detail
    assert np.isnan(force[1000:1400]).all() and not np.isnan(force[1400:]).any()
    assert np.allclose(force[1400:], _reference(p, wf)[1400:], atol=1e-12)


def test_a_host_reading_too_late_overflows_the_buffer_in_real_time():
    import time
    p = _p()
    rig = make_sim_rig(p, realtime=True, connect=True)
    rig.acquisition.buffer_s = 0.2
    wf = _trial_wf(p, n_s=0.8)
    stim, acq = rig.stimulator, rig.acquisition
    stim.load(wf)
    stim.arm()
    acq.start(wf.n_samples)
    stim.start()
    time.sleep(0.5)                              # the host is busy elsewhere
    c = acq.read(0.1)
    assert c.flags.overrun and "overflow" in c.flags.detail
    assert c.start_index >= int(0.25 * FS)       # the oldest samples are gone
    acq.stop()
    stim.stop_now()
