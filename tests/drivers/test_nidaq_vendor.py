"""NI DAQ behaviour as DAQmx documents it (issue 16): each test failed on the old code.

-200019 (ADC overrun) is an overrun, -200141 (counter overflow) is not; the input buffer is
a whole number of callback blocks (else DAQmx -200877) sized from the COERCED rate; after a
USB glitch a new task is built.
"""

from __future__ import annotations

import pytest

from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.nidaq import NidaqAcquisition
from tests.drivers.test_nidaq import CAL, collect


def _rig(fake_mcs, fake_nidaqmx, timebase_Hz=20e6):
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=2.0)
    fake_mcs(bench=bench)
    wiring = bench_mod.sensor_wiring(bench, CAL.channels, {"Fx": CAL.volts_per_unit("Fx")},
                                     direction=(-1.0, 0.0, 0.0), sync_channel=1)
    return bench, fake_nidaqmx(bench=bench, wiring=wiring, devices={
        "Dev1": {"product_type": "USB-6212", "serial_num": 1, "timebase_Hz": timebase_Hz}})


def _first_flagged(acq):
    for _ in range(60):
        c = acq.read(0.05)
        if c is not None and c.flags.any:
            return c
    raise AssertionError("no flagged chunk")


def test_adc_overrun_is_an_overrun_and_counter_overflow_is_not(fake_mcs, fake_nidaqmx):
    bench, state = _rig(fake_mcs, fake_nidaqmx)
    acq = NidaqAcquisition(CAL)
    try:
        acq.configure(2000.0)
        acq.start(None, triggered=False)
        assert collect(acq, 100)
        state.inject_read_error = -200019
        c = _first_flagged(acq)
        assert (c.flags.overrun, c.flags.sensor_fault) == (True, False)
        assert "-200019" in c.flags.detail and "ADC conversion" in c.flags.detail
        state.inject_read_error = -200141
        c = _first_flagged(acq)
        assert (c.flags.overrun, c.flags.sensor_fault) == (False, True)
        assert "counter overflow" in c.flags.detail
    finally:
        acq.close()


@pytest.mark.parametrize("fs_Hz, reads_per_s, timebase_Hz", [
    (2000.0, 30.0, 20e6),    # 2000/30 -> 67-sample blocks, 10000 is not a multiple
    (2100.0, 10.0, 100e3),   # coerced to 2083.3 Hz: 208-sample blocks
    (2000.0, 7.0, 20e6)])
def test_buffer_is_a_whole_number_of_blocks_from_the_coerced_rate(
        fake_mcs, fake_nidaqmx, fs_Hz, reads_per_s, timebase_Hz):
    bench, state = _rig(fake_mcs, fake_nidaqmx, timebase_Hz)
    acq = NidaqAcquisition(CAL, reads_per_s=reads_per_s)
    try:
        rate = acq.configure(fs_Hz)
        expected = timebase_Hz / round(timebase_Hz / fs_Hz)
        assert rate == pytest.approx(expected)
        task = state.tasks[-1]
        assert task.n_every == round(expected / reads_per_s)
        assert task.buffer % task.n_every == 0
        assert task.buffer >= 5.0 * expected
        acq.start(None, triggered=False)  # DAQmx -200877 here on the old sizing
        assert sum(c.n for c in collect(acq, 2 * task.n_every)) >= 2 * task.n_every
    finally:
        acq.close()


def test_fake_refuses_a_buffer_that_is_not_a_multiple_as_daqmx_does(fake_mcs, fake_nidaqmx):
    bench, state = _rig(fake_mcs, fake_nidaqmx)
    mod = load_fake("fake_nidaqmx")
    task = mod.Task("t")
    task.ai_channels.add_ai_voltage_chan("Dev1/ai0")
    task.timing.cfg_samp_clk_timing(2000.0, sample_mode=mod.AcquisitionType.CONTINUOUS,
                                    samps_per_chan=10000)
    task.register_every_n_samples_acquired_into_buffer_event(67, lambda *a: 0)
    with pytest.raises(mod.DaqError) as err:
        task.start()
    assert err.value.error_code == -200877
    task.close()


def test_reconnect_after_usb_glitch_builds_a_new_task(fake_mcs, fake_nidaqmx):
    bench, state = _rig(fake_mcs, fake_nidaqmx)
    mod = load_fake("fake_nidaqmx")
    acq = NidaqAcquisition(CAL)
    try:
        acq.configure(2000.0)
        acq.start(None, triggered=False)
        assert collect(acq, 100)
        mod.unplug()
        c = _first_flagged(acq)
        assert c.flags.sensor_fault and "-201003" in c.flags.detail
        mod.replug()
        old = state.tasks[-1]
        assert acq.reconnect(2000.0) == 2000.0
        assert state.tasks[-1] is not old and old.closed
        acq.start(200, triggered=False)
        chunks = collect(acq, 200)
        assert sum(c.n for c in chunks) == 200 and not any(c.flags.any for c in chunks)
    finally:
        acq.close()
