"""The Contec CAIO driver against the fake CAIO library (ctypes conventions) and bench."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from nmsid.drivers.analog_force import AnalogCalibration
from nmsid.drivers.caio import CaioAcquisition, declare, load_caio
from nmsid.drivers.errors import (
    DeviceError,
    DeviceNotFound,
    HardwareConfigError,
    VendorLibraryMissing,
)
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.stg4002 import Stg4002Stimulator

CAL = AnalogCalibration(channels={"Fx": 0, "Fy": 1, "Fz": 2, "Mx": 3, "My": 4, "Mz": 5},
                        rated={"Fx": 500, "Fy": 500, "Fz": 1000, "Mx": 10, "My": 10, "Mz": 10},
                        rated_output_V=dict.fromkeys(("Fx", "Fy", "Fz", "Mx", "My", "Mz"), 10.0),
                        offset_V={"Fx": 0.1}, sync_channel=6)


def rig(fake_mcs, speed=1.0, wiring=None, **lib_kw):
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=speed)
    fake_mcs(bench=bench)
    if wiring is None:
        wiring = bench_mod.sensor_wiring(bench, CAL.channels,
                                         {a: CAL.volts_per_unit(a) for a in CAL.channels},
                                         offset_V={"Fx": 0.1}, sync_channel=6)
    lib = declare(load_fake("fake_caio").FakeCaioLibrary(bench, wiring=wiring, **lib_kw))
    return bench, lib


def read_all(acq, n, bench, timeout_s=3.0):
    import time
    chunks, got, end = [], 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        c = acq.read(0.05)
        if c is not None:
            chunks.append(c)
            got += c.n
    return chunks


def test_triggered_trial_aligned_to_the_stimulator_sync(fake_mcs):
    bench, lib = rig(fake_mcs, speed=4.0)
    stim = Stg4002Stimulator(ceiling_ext_mA=12, ceiling_flex_mA=12, clock=bench.now)
    stim.connect()
    n = int(0.5 * 2000)
    env = np.full(n, 8.0)
    stim.load(CheckedWaveform(env, np.zeros(n), 2000.0, 1000.0, 12.0, 12.0))
    acq = CaioAcquisition(CAL, lib=lib)
    assert acq.configure(2000.0) == 2000.0
    acq.start(n, triggered=True)
    bench.sleep(0.05)
    assert acq.read(0.01) is None  # waiting for the trigger: nothing converted
    stim.arm()
    stim.start()
    chunks = read_all(acq, n, bench)
    assert sum(c.n for c in chunks) == n
    assert [c.start_index for c in chunks] == list(np.cumsum([0] + [c.n for c in chunks[:-1]]))
    sync = np.concatenate([c.sync for c in chunks])
    assert sync[0] > 3.0 and np.all(sync > 3.0)  # sample 0 is onset: sync already high
    force = np.concatenate([c.force_N for c in chunks])
    assert force[-1] > 0.5 * 8.0 * (8 - 2) / 8  # extensor alone at 8 mA pushes extension
    wrench = np.concatenate([c.wrench for c in chunks])
    np.testing.assert_allclose(wrench[:, 1:], 0.0, atol=0.2)
    assert not any(c.flags.any for c in chunks)
    calls = [c for c in lib.calls if c[0].startswith("AioSet")]
    assert ("AioSetAiChannels", 0, 7) in calls and ("AioSetAiMemoryType", 0, 0) in calls
    assert ("AioSetAiClockType", 0, 0) in calls and ("AioSetAiSamplingClock", 0, 500.0) in calls
    assert ("AioSetAiStartTrigger", 0, 1) in calls and ("AioSetAiStopTrigger", 0, 0) in calls
    assert ("AioSetAiStopTimes", 0, n) in calls
    assert acq.read(0.01) is None  # finished
    acq.close()
    assert lib.calls[-1][0] == "AioExit"


def test_volts_to_newtons_by_hand(fake_mcs):
    wiring = {0: lambda t, f: np.full(len(t), 2.6), 1: lambda t, f: np.full(len(t), -1.0),
              2: lambda t, f: np.zeros(len(t)), 3: lambda t, f: np.full(len(t), 0.5),
              4: lambda t, f: np.zeros(len(t)), 5: lambda t, f: np.zeros(len(t)),
              6: lambda t, f: np.zeros(len(t))}
    bench, lib = rig(fake_mcs, wiring=wiring)
    acq = CaioAcquisition(CAL, lib=lib)
    acq._tare.measured = True   # the configured offsets: scaling by hand, no tare
    acq.configure(2000.0)
    acq.start(20, triggered=False)
    c = read_all(acq, 20, bench)[0]
    lsb = 20.0 / 65536
    np.testing.assert_allclose(c.force_N, (2.6 - 0.1) * 50.0, atol=50 * lsb)  # (V-off)*500/10
    np.testing.assert_allclose(c.wrench[:, 1], -50.0, atol=50 * lsb)
    np.testing.assert_allclose(c.wrench[:, 3], 0.5, atol=lsb)
    acq.close()


def test_fifo_overflow_is_overrun(fake_mcs):
    bench, lib = rig(fake_mcs, speed=10.0, fifo_samples=200)
    acq = CaioAcquisition(CAL, lib=lib)
    acq.configure(2000.0)
    acq._tare.measured = True   # a 200-sample FIFO at 10x overflows in a tare window too
    acq.start(None, triggered=False)
    bench.sleep(0.3)  # 600 samples due, FIFO holds 200
    c = acq.read(0.05)
    assert c.flags.overrun and "FIFO overflow" in c.flags.detail
    acq.close()


@pytest.mark.parametrize("bit, flag, text", [(0x20000, "overrun", "clock error"),
                                             (0x40000, "sensor_fault", "conversion error"),
                                             (0x80000, "sensor_fault", "driver error")])
def test_status_errors_become_flags(fake_mcs, bit, flag, text):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib)
    acq.configure(2000.0)
    acq.start(None, triggered=True)  # no trigger: no data, the flag must still come out
    lib.inject_status = bit
    c = acq.read(0.05)
    assert c is not None and c.n == 0 and getattr(c.flags, flag) and text in c.flags.detail
    acq.close()


def test_saturation_is_over_range(fake_mcs):
    wiring = {ch: (lambda t, f: np.full(len(t), 10.0)) for ch in range(7)}
    bench, lib = rig(fake_mcs, wiring=wiring)
    acq = CaioAcquisition(CAL, lib=lib)
    acq.configure(2000.0)
    with pytest.raises(DeviceError, match="no-load voltages"):   # no tare at saturation
        acq.start(10, triggered=False)
    acq._tare.measured = True   # the configured offsets: the flag itself, no tare
    acq.start(10, triggered=False)
    c = read_all(acq, 10, bench)[0]
    assert c.flags.over_range and "edge" in c.flags.detail
    acq.close()


def test_unplugged_during_acquisition_is_sensor_fault(fake_mcs):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib)
    acq.configure(2000.0)
    acq.start(None, triggered=False)
    lib.plugged = False
    c = acq.read(0.05)
    assert c.flags.sensor_fault and "AioGetAiStatus" in c.flags.detail
    assert "error 10002" in c.flags.detail  # AIO_ERR_DLL_CALL_DRIVER (Contec's number)
    acq.close()  # never raises


def test_device_not_found(fake_mcs):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib, device_name="AIO007")
    with pytest.raises(DeviceNotFound, match="'AIO007' not found.*error 10000.*not registered"):
        acq.configure(2000.0)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="range 'PM3'"):
        CaioAcquisition(CAL, ai_range="PM3", lib=object())
    with pytest.raises(ValueError, match="input_method"):
        CaioAcquisition(CAL, input_method="pseudo", lib=object())


def test_fake_enforces_ctypes_conventions(fake_mcs):
    bench, _ = rig(fake_mcs)
    raw = load_fake("fake_caio").FakeCaioLibrary(bench)
    with pytest.raises(RuntimeError, match="argtypes not declared"):
        raw.AioExit(ctypes.c_short(0))
    lib = declare(raw)
    with pytest.raises(ctypes.ArgumentError):
        lib.AioGetAiStatus(ctypes.c_short(0), 5)  # must be byref(c_long)


def test_missing_library_is_one_clear_line():
    with pytest.raises(VendorLibraryMissing) as info:
        load_caio("/nonexistent/libcaio.so")
    msg = str(info.value)
    assert "\n" not in msg and "CAIO" in msg and "API-AIO" in msg


def test_monitor_channel_rides_in_the_same_scan_and_channels_are_converted_in_turn(fake_mcs):
    """The dry run's monitor input comes back raw (volts) in ``ForceChunk.monitor``; each
    channel of a scan is converted ``conversion_us`` after the previous one (Contec's
    10 us/channel; the driver's ``sample_delay_s`` says the same)."""
    ramp_V_per_s = 1000.0                                   # 1 V per ms: 10 us = 10 mV
    # a sawtooth of 8 V per 8 ms: inside the +-10 V range whenever the scan happens (it
    # used to be a ramp from the last whole second, clipped 10 ms into any second: the test
    # then depended on when a loaded machine got to sample); compared modulo 8 V below
    wiring = {ch: (lambda t, f: np.mod(ramp_V_per_s * t, 8.0)) for ch in range(8)}
    bench, lib = rig(fake_mcs, wiring=wiring)
    cal = AnalogCalibration(**{**CAL.__dict__, "monitor_channel": 7})
    assert cal.n_channels == 8
    acq = CaioAcquisition(cal, lib=lib)
    acq._tare.measured = True   # the configured offsets: scaling by hand, no tare
    acq.configure(1000.0)
    acq.start(5, triggered=False)
    c = read_all(acq, 5, bench)[0]
    assert c.monitor is not None and c.monitor.shape == (c.n,)
    np.testing.assert_allclose(np.mod(c.monitor - c.sync + 4.0, 8.0) - 4.0,
                               (7 - 6) * 10e-6 * ramp_V_per_s, atol=2 * 20 / 65536)
    assert acq.sample_delay_s(7) - acq.sample_delay_s(6) == pytest.approx(10e-6)
    acq.close()


@pytest.mark.parametrize("fs_Hz, channels, ok", [(12_500.0, 8, True), (12_600.0, 8, False),
                                                 (50_000.0, 2, True), (2000.0, 16, True),
                                                 (7000.0, 16, False)])
def test_sampling_clock_faster_than_the_conversions_is_refused(fake_mcs, fs_Hz, channels, ok):
    """Contec: the sampling clock must be at least channels x conversion speed (help,
    "Sampling clock period error"); the driver says so before the device stops with
    AIS_SCERR."""
    bench, lib = rig(fake_mcs, wiring={})
    cal = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500}, rated_output_V={"Fx": 10},
                            sync_channel=channels - 1)
    acq = CaioAcquisition(cal, lib=lib)
    if ok:
        assert acq.configure(fs_Hz) == pytest.approx(fs_Hz, rel=1e-3)
    else:
        with pytest.raises(HardwareConfigError, match="acquisition.caio.conversion_us"):
            acq.configure(fs_Hz)
    acq.close()
