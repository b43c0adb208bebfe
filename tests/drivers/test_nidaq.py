"""The NI DAQ driver against the fake nidaqmx (callback thread, stream reader, trigger)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from nmsid.drivers.analog_force import AnalogCalibration
from nmsid.drivers.errors import DeviceNotFound, HardwareConfigError, VendorLibraryMissing
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.nidaq import NidaqAcquisition, load_nidaqmx
from nmsid.drivers.stg4002 import Stg4002Stimulator

CAL = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0}, rated_output_V={"Fx": 5.0},
                        sync_channel=1, extension_direction=(-1.0, 0.0, 0.0))


def setup_rig(fake_mcs, fake_nidaqmx, speed=4.0):
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=speed)
    fake_mcs(bench=bench)
    wiring = bench_mod.sensor_wiring(bench, CAL.channels, {"Fx": CAL.volts_per_unit("Fx")},
                                     direction=(-1.0, 0.0, 0.0), sync_channel=1)
    state = fake_nidaqmx(bench=bench, wiring=wiring)
    return bench, state


def collect(acq, n, timeout_s=3.0):
    chunks, got, end = [], 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        c = acq.read(0.05)
        if c is not None:
            chunks.append(c)
            got += c.n
    return chunks


def test_triggered_trial_through_every_n_samples_callback(fake_mcs, fake_nidaqmx):
    bench, state = setup_rig(fake_mcs, fake_nidaqmx)
    stim = Stg4002Stimulator(ceiling_ext_mA=12, ceiling_flex_mA=12, clock=bench.now)
    stim.connect()
    n = 1000
    stim.load(CheckedWaveform(np.zeros(n), np.full(n, 9.0), 2000.0, 1000.0, 12.0, 12.0))
    acq = NidaqAcquisition(CAL, device="Dev1", start_trigger="/Dev1/PFI0")
    assert acq.configure(2000.0) == 2000.0
    task = state.tasks[-1]
    assert task.ai_channels.names == ["Dev1/ai0", "Dev1/ai1"]
    assert task.n_every == 200 and task.mode.name == "CONTINUOUS"
    acq.start(n, triggered=True)
    assert task.triggers.start_trigger.source == "/Dev1/PFI0"
    bench.sleep(0.05)
    assert acq.read(0.02) is None  # no trigger yet
    stim.arm()
    stim.start()
    chunks = collect(acq, n)
    assert sum(c.n for c in chunks) == n and all(c.n <= 200 for c in chunks)
    assert [c.start_index for c in chunks] == list(np.cumsum([0] + [c.n for c in chunks[:-1]]))
    sync = np.concatenate([c.sync for c in chunks])
    assert np.all(sync > 3.0)
    force = np.concatenate([c.force_N for c in chunks])
    # flexor only at 9 mA: activation 7/8 -> about -7 N along extension
    assert force[-1] < -3.0
    assert chunks[0].wrench is None  # not all six axes wired
    acq.stop()
    acq.close()
    assert task.closed


def test_read_errors_become_flags(fake_mcs, fake_nidaqmx):
    bench, state = setup_rig(fake_mcs, fake_nidaqmx, speed=2.0)
    acq = NidaqAcquisition(CAL)
    acq.configure(2000.0)
    acq.start(None, triggered=False)
    assert collect(acq, 200)
    state.inject_read_error = -200279
    c = None
    for _ in range(40):
        c = acq.read(0.05)
        if c is not None and c.flags.any:
            break
    assert c.flags.overrun and "-200279" in c.flags.detail
    state.inject_read_error = -50103
    for _ in range(40):
        c = acq.read(0.05)
        if c is not None and c.flags.any:
            break
    assert c.flags.sensor_fault and not c.flags.overrun
    acq.close()


def test_blocks_of_a_previous_trial_are_dropped(fake_mcs, fake_nidaqmx):
    bench, state = setup_rig(fake_mcs, fake_nidaqmx, speed=4.0)
    acq = NidaqAcquisition(CAL)
    acq.configure(2000.0)
    acq.start(None, triggered=False)
    bench.sleep(0.3)
    acq.stop()
    acq.start(400, triggered=False)
    chunks = collect(acq, 400)
    assert chunks[0].start_index == 0 and sum(c.n for c in chunks) == 400
    acq.close()


def test_unknown_device(fake_mcs, fake_nidaqmx):
    setup_rig(fake_mcs, fake_nidaqmx)
    with pytest.raises(DeviceNotFound, match="'Dev9'.*NI MAX"):
        NidaqAcquisition(CAL, device="Dev9").configure(2000.0)


def test_settings_refused():
    with pytest.raises(ValueError, match="terminal_config 'DIFFERENTIAL'"):
        NidaqAcquisition(CAL, terminal_config="DIFFERENTIAL")


def test_missing_nidaqmx_is_one_clear_line(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    with pytest.raises(VendorLibraryMissing) as info:
        load_nidaqmx()
    assert "\n" not in str(info.value) and "nmsid[nidaq]" in str(info.value)


@pytest.mark.parametrize("fs_Hz, simultaneous, refused", [(200e3, False, False),
                                                          (200_001.0, False, True),
                                                          (250e3, True, False)])
def test_aggregate_rate_of_a_multiplexed_device(fake_mcs, fake_nidaqmx, fs_Hz, simultaneous,
                                                refused):
    """2 channels share a 400 kS/s multiplexed ADC (``ai_max_multi_chan_rate``): 200 kHz
    each at most; a simultaneous-sampling device has no such limit."""
    bench = load_fake("bench").FakeBench()
    fake_mcs(bench=bench)
    fake_nidaqmx(bench=bench, devices={"Dev1": {
        "product_type": "USB-6212", "serial_num": 1,
        "ai_simultaneous_sampling_supported": simultaneous}})
    acq = NidaqAcquisition(CAL, device="Dev1")
    if refused:
        with pytest.raises(HardwareConfigError, match="at most 400 kS/s over all channels"):
            acq.configure(fs_Hz)
    else:
        assert acq.configure(fs_Hz) == pytest.approx(fs_Hz, rel=1e-4)
        expected_s = 0.0 if simultaneous else 1 / max(80e3, 2 * fs_Hz)
        assert acq.sample_delay_s(1) == pytest.approx(expected_s)
    acq.close()
