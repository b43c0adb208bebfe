"""NI DAQ against nidaqmx 1.7.0's documented API (issue 25, "NI"): the start trigger's
default derived from the device, channels and terminal configurations checked against
``Device.ai_physical_chans`` / ``PhysicalChannel.ai_term_cfgs``, a unique task name (DAQmx
-200089 on a name in use), and the E-stop line that shares a pin with PFI0. The fake
honours the trigger source and the channel names (testing/fakes/fake_nidaqmx.py).
"""

from __future__ import annotations

import pytest

from nmsid.drivers.analog_force import AnalogCalibration
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.hw_config import parse_hw_config
from nmsid.drivers.nidaq import NidaqAcquisition, shared_pin
from tests.drivers.test_nidaq import CAL, collect


def _rig(fake_mcs, fake_nidaqmx, device="Lab2", **entry):
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=2.0)
    fake_mcs(bench=bench)
    wiring = bench_mod.sensor_wiring(bench, CAL.channels, {"Fx": CAL.volts_per_unit("Fx")},
                                     direction=(-1.0, 0.0, 0.0), sync_channel=1)
    state = fake_nidaqmx(bench=bench, wiring=wiring, devices={
        device: {"product_type": "USB-6212", "serial_num": 1, **entry}})
    return bench, state


def test_the_start_trigger_defaults_to_the_devices_own_pfi0(fake_mcs, fake_nidaqmx):
    # the old default "/Dev1/PFI0" on a device named Lab2: DAQmx refuses the terminal
    bench, state = _rig(fake_mcs, fake_nidaqmx, device="Lab2")
    acq = NidaqAcquisition(CAL, device="Lab2")
    assert acq.start_trigger == "/Lab2/PFI0"
    try:
        acq.configure(2000.0)
        acq.start(200, triggered=True)
        assert state.tasks[-1].triggers.start_trigger.source == "/Lab2/PFI0"
    finally:
        acq.close()


@pytest.mark.parametrize("terminal, starts", [("/Dev1/PFI1", True), ("/Dev1/PFI0", False)])
def test_the_fake_honours_the_trigger_source(fake_mcs, fake_nidaqmx, terminal, starts):
    bench, state = _rig(fake_mcs, fake_nidaqmx, device="Dev1", sync_terminal="/Dev1/PFI1")
    t_sync = bench.now() + 0.05
    bench.trigger_time = lambda: t_sync if bench.now() >= t_sync else None  # a sync edge
    acq = NidaqAcquisition(CAL, device="Dev1", start_trigger=terminal)
    try:
        acq.configure(2000.0)
        acq._tare.measured = True   # the sync edge is 50 ms away: no tare window first
        acq.start(100, triggered=True)
        got = collect(acq, 100, timeout_s=0.6)
        assert (sum(c.n for c in got) == 100) is starts
    finally:
        acq.close()


def test_channels_the_device_lacks_are_refused_before_a_task_is_made(fake_mcs, fake_nidaqmx):
    bench, state = _rig(fake_mcs, fake_nidaqmx, device="Dev1", n_ai=8)
    cal = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                            rated_output_V={"Fx": 1.0}, sync_channel=9)
    acq = NidaqAcquisition(cal, device="Dev1", terminal_config="RSE")
    with pytest.raises(HardwareConfigError, match=r"has no Dev1/ai8, Dev1/ai9 .* it has "
                                                  r"Dev1/ai0, Dev1/ai1"):
        acq.configure(2000.0)
    assert state.tasks == []


def test_a_terminal_configuration_a_channel_lacks_is_refused(fake_mcs, fake_nidaqmx):
    # M-series: ai8..ai15 pair with ai0..ai7 in DIFF and have no DIFF of their own
    bench, state = _rig(fake_mcs, fake_nidaqmx, device="Dev1")
    cal = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                            rated_output_V={"Fx": 1.0}, sync_channel=8)
    acq = NidaqAcquisition(cal, device="Dev1", terminal_config="DIFF")
    with pytest.raises(HardwareConfigError, match=r"'DIFF' is not supported by Dev1/ai8 "
                                                  r"\(RSE/NRSE\)"):
        acq.configure(2000.0)
    acq = NidaqAcquisition(cal, device="Dev1", terminal_config="RSE")
    acq.configure(2000.0)
    acq.close()


def test_task_names_are_unique(fake_mcs, fake_nidaqmx):
    bench, state = _rig(fake_mcs, fake_nidaqmx, device="Dev1")
    stale = state.tasks  # a task of a crashed session with the old fixed name
    load_fake("fake_nidaqmx").Task("nmsid-force")
    a, b = NidaqAcquisition(CAL, device="Dev1"), NidaqAcquisition(CAL, device="Dev1")
    try:
        a.configure(2000.0)
        b.configure(2000.0)   # was: DAQmx -200089, task name in use
        names = [t.name for t in stale if t.name.startswith("nmsid-force-")]
        assert len(set(names)) == 2
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("line, trig, same", [
    ("Dev1/port1/line0", "/Dev1/PFI0", True), ("Dev1/port2/line1", "/Dev1/PFI9", True),
    ("Dev1/port0/line0", "/Dev1/PFI0", False), ("Dev1/port1/line1", "/Dev1/PFI0", False),
    ("Dev2/port1/line0", "/Dev1/PFI0", False)])
def test_an_estop_line_on_the_trigger_pin_is_found(line, trig, same):
    assert bool(shared_pin(line, trig)) is same


def test_the_hardware_file_refuses_an_estop_on_the_trigger_pin():
    base = {"acquisition": {"kind": "nidaq", "fs_Hz": 2000.0, "nidaq": {"device": "Dev1"}},
            "sensor": {"channels": {"Fx": 0}, "rated": {"Fx": 500.0},
                       "rated_output_V": {"Fx": 1.0}, "sync_channel": 1}}
    with pytest.raises(HardwareConfigError, match="same pin"):
        parse_hw_config({**base, "estop": {"kind": "nidaq", "line": "Dev1/port1/line0"}},
                        "hw.toml")
    parse_hw_config({**base, "estop": {"kind": "nidaq", "line": "Dev1/port0/line0"}},
                    "hw.toml")
