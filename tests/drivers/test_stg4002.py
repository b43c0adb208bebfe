"""The STG4002 driver against the fake McsUsbNet: what reaches the device, sample by sample."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers.errors import (
    DeviceError,
    DeviceMemoryError,
    DeviceNotFound,
    DeviceRangeError,
    VendorLibraryMissing,
)
from nmsid.drivers.interfaces import CheckedWaveform, CurrentLimitError, StimulatorState
from nmsid.drivers.stg4002 import Stg4002Stimulator, load_mcs_usb
from nmsid.drivers.stg_waveform import render_channel

FS = 2000.0
FC = 1000.0
RATE = 50_000.0


def waveform(seconds=0.5, ceiling=12.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS)) / FS
    ext = np.clip(6 + 4 * np.sin(2 * np.pi * 3 * t) + rng.uniform(-1, 1, len(t)), 0, ceiling)
    flex = np.clip(5 - 3 * np.sin(2 * np.pi * 3 * t), 0, ceiling)
    ext[-10:] = ceiling  # exactly at the ceiling
    return CheckedWaveform(ext, flex, FS, FC, ceiling, ceiling)


def stim(**kw):
    args = {"ceiling_ext_mA": 12.0, "ceiling_flex_mA": 12.0, "dll_path": "C:/mcs/McsUsbNet.dll"}
    args.update(kw)
    return Stg4002Stimulator(**args)


def period_envelope(env_mA, n):
    """Independent reference: the held envelope averaged over each 1 ms carrier period."""
    per = int(RATE / FC)
    j = np.arange(n)
    k = np.minimum((j * FS / RATE + 1e-9).astype(int), len(env_mA) - 1)
    m = n // per
    held = env_mA[k[:m * per]].reshape(m, per)
    return np.repeat(np.minimum(held.mean(axis=1), held.max(axis=1)), per), m * per


def demodulation_check(samples_nA, env_mA, ceiling_mA, resolution_nA):
    """Sample by sample: |I| <= ceiling; I / sin(carrier) equals the per-period envelope."""
    n = len(samples_nA)
    j = np.arange(n)
    s = np.sin(2 * np.pi * FC * j / RATE)
    assert np.abs(samples_nA).max() <= ceiling_mA * 1e6
    ref, m = period_envelope(env_mA, n)
    assert np.all(samples_nA[m:] == 0)  # after the last whole period: nothing
    ok = np.abs(s[:m]) > 0.2
    demod_mA = samples_nA[:m][ok] / s[:m][ok] / 1e6
    err = ref[ok] - demod_mA
    # quantised toward zero: never above the envelope, at most one step below
    assert err.min() >= -1e-9
    assert (err * np.abs(s[:m][ok]) * 1e6).max() <= resolution_nA + 1e-6
    # independent lock-in demodulation over each full carrier period
    per = int(RATE / FC)
    lockin = 2 * (samples_nA[:m] * s[:m]).reshape(-1, per).mean(axis=1) / 1e6
    np.testing.assert_allclose(lockin, ref[::per], atol=2 * resolution_nA / 1e6)
    # charge balance: every carrier period sums to exactly zero
    assert np.all(samples_nA[:m].reshape(-1, per).sum(axis=1) == 0)


def test_vendor_sequence_and_waveform_reaching_the_device(fake_mcs):
    reg = fake_mcs()
    st_ = stim()
    st_.connect()
    assert reg.references == ["C:/mcs/McsUsbNet.dll"]
    caps = st_.capabilities()
    assert (caps.max_current_mA, caps.resolution_mA, caps.output_rate_Hz) == (16.0, 0.0005, RATE)
    assert caps.firmware == "software 1.34, hardware Rev. B"
    wf = waveform()
    st_.load(wf)
    dev = reg.devices[-1]
    names = [c[0] for c in dev.calls]
    assert names.index("SetCurrentMode") < names.index("PrepareAndSendData")
    assert dev.trigger_setup == (0, [0b11, 0], [0b01, 0], [1, 0])
    for ch, env in ((0, wf.I_ext_mA), (1, wf.I_flex_mA)):
        samples = dev._expanded[ch]
        assert len(samples) == int(wf.duration_s * RATE) + 1 and samples[-1] == 0
        demodulation_check(samples[:-1], env, 12.0, 500)
    sync = dev._sync_expanded[0]
    assert (sync[:-1] & 1).tolist() == [1] * int(wf.duration_s * RATE) and sync[-1] == 0
    st_.arm()
    st_.start()
    assert [c for c in dev.calls if c[0] == "SendStart"][-1] == ("SendStart", 1)
    assert st_.status().state is StimulatorState.RUNNING and st_.status().output_active
    st_.stop_now()
    st_.stop_now()  # idempotent
    assert dev.calls[-1] == ("SendStop", 0b11)  # every trigger input
    assert not st_.status().output_active
    st_.disconnect()
    assert [c[0] for c in dev.calls[-4:]] == ["SendStop", "QueryTriggerstatus", "Disconnect",
                                              "Dispose"]
    assert dev.calls[-4][1:] == (0b11, 0x80)  # the save stop at an ordinary end
    assert reg.hardware[0].overlaps == []


def test_status_ends_after_the_trial(fake_mcs):
    fake_mcs()
    bench = fake_mcs.bench
    st_ = stim(clock=bench.now)
    st_.connect()
    st_.load(waveform(seconds=0.05))
    st_.arm()
    st_.start()
    bench.sleep(0.08)
    assert st_.status().state is StimulatorState.STOPPED


def test_stop_now_from_many_threads_while_running(fake_mcs):
    reg = fake_mcs()
    st_ = stim()
    st_.connect()
    st_.load(waveform())
    st_.arm()
    st_.start()
    threads = [threading.Thread(target=st_.stop_now) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    dev = reg.devices[-1]
    assert dev.stopped_at is not None
    names = [c[0] for c in dev.calls]
    stops = names[names.index("SendStart"):].count("SendStop")
    assert 1 <= stops <= 8  # concurrent requests may share one SendStop, never overlap
    assert reg.hardware[0].overlaps == []
    assert not st_.status().output_active


def test_stop_now_never_raises_even_if_the_device_is_gone(fake_mcs):
    reg = fake_mcs()
    st_ = stim()
    st_.connect()
    reg.hardware[0].plugged = False
    st_.stop_now()  # SendStop raises inside; swallowed and logged
    assert "SendStop failed" in st_.status().error


def test_ceiling_above_device_range_is_refused_at_connect(fake_mcs):
    fake_mcs()
    with pytest.raises(DeviceRangeError, match="20 mA on stimulator channel 1 exceeds the "
                                               "device's range 16 mA"):
        stim(ceiling_ext_mA=20.0).connect()


def test_waveform_ceiling_above_rig_ceiling_sends_nothing(fake_mcs):
    reg = fake_mcs()
    st_ = stim(ceiling_ext_mA=8.0)
    st_.connect()
    with pytest.raises(DeviceRangeError, match="rig ceiling 8 mA"):
        st_.load(waveform(ceiling=12.0))
    assert not any(c[0] == "PrepareAndSendData" for c in reg.devices[-1].calls)


def test_memory_too_small_sends_nothing(fake_mcs):
    hw = fake_mcs.module.FakeStgHardware(memory_bytes=100_000)
    reg = fake_mcs(hardware=[hw])
    st_ = stim()
    st_.connect()
    with pytest.raises(DeviceMemoryError, match="MB of STG memory"):
        st_.load(waveform(seconds=1.0))
    assert not any(c[0] == "PrepareAndSendData" for c in reg.devices[-1].calls)


def test_vendor_failure_during_download_is_a_device_error(fake_mcs):
    reg = fake_mcs()
    st_ = stim()
    st_.connect()
    reg.devices[-1].fail_next["PrepareAndSendData"] = RuntimeError("USB stall")
    with pytest.raises(DeviceError, match="USB stall"):
        st_.load(waveform())
    assert st_.status().state is StimulatorState.ERROR
    with pytest.raises(DeviceError):
        st_.arm()


def test_discovery_errors(fake_mcs):
    mod = fake_mcs.module
    fake_mcs(hardware=[])
    with pytest.raises(DeviceNotFound, match="no MCS STG"):
        stim().connect()
    fake_mcs(hardware=[mod.FakeStgHardware(serial="A"), mod.FakeStgHardware(serial="B")])
    with pytest.raises(DeviceNotFound, match="2 STGs found.*stimulator.serial"):
        stim().connect()
    with pytest.raises(DeviceNotFound, match="serial 'C'.*found: A, B"):
        stim(serial="C").connect()
    s = stim(serial="B")
    s.connect()
    assert s.capabilities().serial == "B"


def test_bad_channel_numbers(fake_mcs):
    fake_mcs()
    with pytest.raises(ValueError, match="channel 3 does not exist"):
        stim(flexor_channel=3).connect()
    with pytest.raises(ValueError, match="differ"):
        stim(flexor_channel=1)


def test_missing_pythonnet_is_one_clear_line(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "clr", None)
    monkeypatch.setitem(sys.modules, "pythonnet", None)  # imported first on Windows
    with pytest.raises(VendorLibraryMissing) as info:
        load_mcs_usb("x.dll")
    msg = str(info.value)
    assert "\n" not in msg and "pythonnet" in msg and "pip install" in msg
    assert info.value.name is None


def test_missing_dll_is_one_clear_line(fake_mcs, monkeypatch):
    import sys
    clr = sys.modules["clr"]

    def refuse(path):
        raise RuntimeError("System.IO.FileNotFoundException")
    monkeypatch.setattr(clr, "AddReference", refuse)
    with pytest.raises(VendorLibraryMissing, match=r"McsUsbNet.dll \(x.dll\).*dll_path"):
        load_mcs_usb("x.dll")


@settings(max_examples=25, deadline=None)
@given(ceiling=st.floats(0.5, 16.0), res=st.sampled_from([100, 244, 500, 1000]),
       seed=st.integers(0, 10_000), n=st.integers(2, 120))
def test_rendered_never_exceeds_ceiling_and_demodulates_to_envelope(ceiling, res, seed, n):
    rng = np.random.default_rng(seed)
    env = rng.uniform(0, ceiling, n)
    env[rng.integers(0, n)] = ceiling
    ch = render_channel(env, FS, FC, RATE, res)
    samples = ch.expand()
    assert samples[-1] == 0
    demodulation_check(samples[:-1].astype(float), env, ceiling, res)


def test_last_check_refuses_a_rendered_point_above_the_ceiling():
    from nmsid.drivers.stg_waveform import RenderedChannel, check_rendered
    ok = RenderedChannel(np.array([0, 4_000_000, -4_000_000, 0], dtype=np.int32),
                         np.array([20, 20, 20, 20], dtype=np.uint64), 20)
    check_rendered(ok, 4.0, "extensor")
    with pytest.raises(CurrentLimitError, match="extensor: rendered point 1 = 4.0000 mA "
                                                "exceeds the ceiling 3.9990 mA"):
        check_rendered(ok, 3.999, "extensor")
    not_ending = RenderedChannel(np.array([0, 1000], dtype=np.int32),
                                 np.array([20, 20], dtype=np.uint64), 20)
    with pytest.raises(CurrentLimitError, match="does not end at 0 nA"):
        check_rendered(not_ending, 4.0, "flexor")


def test_quantisation_is_toward_zero_exactly_at_the_ceiling():
    # envelope exactly at a ceiling that is not a multiple of the resolution
    env = np.full(40, 7.3333)
    samples = render_channel(env, FS, FC, RATE, 500).expand()
    assert np.abs(samples).max() <= 7.3333e6
    peak_sin = np.abs(np.sin(2 * np.pi * FC * np.arange(50) / RATE)).max()  # off-grid peak
    assert np.abs(samples).max() >= 7.3333e6 * peak_sin - 500


def test_next_trial_loads_after_the_previous_one_ended(fake_mcs):
    fake_mcs()
    bench = fake_mcs.bench
    st_ = stim(clock=bench.now)
    st_.connect()
    st_.load(waveform(seconds=0.02))
    st_.arm()
    st_.start()
    with pytest.raises(DeviceError, match="running"):
        st_.load(waveform(seconds=0.02))
    bench.sleep(0.05)
    st_.load(waveform(seconds=0.02))  # ended on its own: no stop_now needed
    assert st_.status().state is StimulatorState.LOADED
