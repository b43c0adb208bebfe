"""The Contec CAIO driver against the fake CAIO library (ctypes conventions) and bench."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from nmsid.drivers.analog_force import AnalogCalibration
from nmsid.drivers.caio import CaioAcquisition, declare, load_caio
from nmsid.drivers.errors import DeviceNotFound, VendorLibraryMissing
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.stg4002 import Stg4002Stimulator

CAL = AnalogCalibration(channels={"Fx": 0, "Fy": 1, "Fz": 2, "Mx": 3, "My": 4, "Mz": 5},
                        rated={"Fx": 500, "Fy": 500, "Fz": 1000, "Mx": 10, "My": 10, "Mz": 10},
                        rated_output_V={a: 10.0 for a in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")},
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
    assert "Invalid ID" in c.flags.detail
    acq.close()  # never raises


def test_device_not_found(fake_mcs):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib, device_name="AIO007")
    with pytest.raises(DeviceNotFound, match="'AIO007' not found.*Invalid device name"):
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
