"""``nmsid probe --dry-run`` end to end on the fake rig: the fake STG's real output across a
simulated resistor into the fake A/D's monitor input, read by the SAME CAIO / NI drivers
as a session (one triggered scan of force, sync and monitor); the checks failing when the
loop-back does not match; refusals before anything is stimulated."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.cli import main
from nmsid.drivers.dry_run import DryRunSettings, check_loopback
from nmsid.drivers.errors import HardwareConfigError, StimulatorSettingError
from nmsid.drivers.hardware import build_devices, with_monitor
from nmsid.drivers.hw_config import load_hw_config
from nmsid.drivers.registry import stimulator_kind
from nmsid.rig.dry_run import run_dry_run

CHECKS = ("onset", "force record", "amplitude", "carrier", "envelope", "charge balance")


@pytest.fixture(autouse=True)
def _queued_ahead(deep_fake_fifo, monkeypatch):
    # the deep FIFO (conftest), and the probe's streamed trial queued 0.8 s ahead, not
    # 0.5 s, for the same reason (the stream running dry: test_dry_run_engine.py)
    monkeypatch.setattr("nmsid.rig.dry_run.STREAM_QUEUE_S", 0.8)


@pytest.mark.parametrize("kind, monitor", [("caio", 7), ("caio", 9), ("nidaq", 7)])
def test_probe_dry_run_passes_every_check_on_the_fake_rig(tmp_path, write_hw_config, capsys,
                                                          kind, monitor):
    hw = write_hw_config(tmp_path / "hw.toml", kind=kind, speed=1.0, estop="none",
                         monitor=monitor)
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 0
    out = capsys.readouterr().out
    for name in CHECKS:
        assert f"[PASS] {name}:" in out
    assert "[FAIL]" not in out and "dry run: OK" in out
    assert "10000 of 10000 samples at 10000 Hz" in out
    assert "1000.00 Hz" in out
    # the fake A/Ds convert channel by channel: the monitor is sampled after the scan's
    # edge (CAIO 10 us per channel, the fake NI's convert clock 80 kHz); corrected
    delay_s = monitor * 10e-6 if kind == "caio" else monitor / 80e3
    assert f"scan delay {delay_s * 1e3:.3f} ms corrected" in out


def _run(tmp_path, write_hw_config, *, wired_channel=0, actual_ohm=1000.0, kind="caio",
         extra=(), monitor=7, estop_at_s=None, **settings):
    hw = write_hw_config(tmp_path / "hw.toml", kind=kind, speed=1.0, estop="none",
                         monitor=monitor, extra=extra)
    cfg = with_monitor(load_hw_config(hw))
    devices = build_devices(cfg)
    lines: list[str] = []
    try:
        devices.stimulator.connect()
        devices.clock.bench.dummy_load = (wired_channel, actual_ohm)  # what is really wired
        ok = run_dry_run(devices, DryRunSettings(**settings),
                         stimulator_kind(cfg.stimulator).dry_run, out=lines.append,
                         monitor_channel=monitor, estop_at_s=estop_at_s)
    finally:
        devices.close()
    return ok, "\n".join(lines)


def test_a_wrong_resistor_fails_the_amplitude_check(tmp_path, write_hw_config):
    ok, text = _run(tmp_path, write_hw_config, actual_ohm=1500.0)
    assert not ok
    amp = next(line for line in text.splitlines() if "amplitude" in line)
    assert amp.startswith("  [FAIL] amplitude: max error ")
    pct = float(amp.split("(")[1].split("%")[0])
    assert pct == pytest.approx(50.0, abs=1.0)        # 1.5 kOhm read as 1 kOhm: +50 %
    assert "[PASS] carrier" in text and "[PASS] envelope" in text


def test_the_resistor_on_the_other_channel_fails(tmp_path, write_hw_config):
    ok, text = _run(tmp_path, write_hw_config, wired_channel=1)   # flexor output: 0 mA
    assert not ok and "[FAIL] amplitude" in text and "[FAIL] envelope" in text


def test_a_record_at_20_kHz_also_passes(tmp_path, write_hw_config):
    ok, text = _run(tmp_path, write_hw_config, kind="nidaq", monitor_fs_Hz=20_000.0)
    assert ok, text
    assert "20000 of 20000 samples at 20000 Hz" in text


def test_a_conversion_time_set_too_short_meets_the_devices_clock_error(tmp_path,
                                                                      write_hw_config):
    """With acquisition.caio.conversion_us = 5 the driver lets 12.5 kHz x 8 channels
    through; the (fake) AI-1608AY-USB, at 10 us per channel, sets AIS_SCERR and stops
    (Contec: "Sampling clock period error"): the dry run fails, already on the no-load
    window (the automatic tare) that precedes the record."""
    ok, text = _run(tmp_path, write_hw_config, monitor_fs_Hz=16_000.0,
                    extra=("[acquisition.caio]", "conversion_us = 5.0"))
    assert not ok
    assert "could not be measured: sampling clock error (AIS_SCERR)" in text, text
    assert "[PASS]" not in text


def test_unbalanced_late_or_untriggered_current_is_caught():
    s = DryRunSettings(monitor_fs_Hz=20_000.0)
    fs, n = s.monitor_fs_Hz, 20_000
    t = np.arange(n) / fs
    cmd = 2e-3 * np.sin(2 * np.pi * 1000 * t)
    sync = np.full(n, 3.3)
    ok = check_loopback(cmd * 1000, sync, cmd, s, 3.3)
    assert all(c.passed for c in ok)
    dc = check_loopback((cmd + 0.2e-3) * 1000, sync, cmd, s, 3.3)   # 0.2 mA offset
    bal = next(c for c in dc if c.name == "charge balance")
    assert not bal.passed and "worst net 200.000 nC" in bal.figure
    late = np.roll(cmd, 5)                                       # 0.25 ms late
    onset = next(c for c in check_loopback(late * 1000, sync, cmd, s, 3.3)
                 if c.name == "onset")
    assert not onset.passed and "+0.250 ms" in onset.figure
    untriggered = next(c for c in check_loopback(cmd * 1000, sync, cmd, s, 0.0)
                       if c.name == "force record")
    assert not untriggered.passed


@pytest.mark.parametrize("delay_us", [-80.0, -30.0, 12.5, 45.0, 95.0])
def test_onset_is_measured_below_one_sample(delay_us):
    """A current late by a fraction of a 100 us sample is measured to a few us (closed
    form: the carrier's phase), and a known A/D scan delay is added back."""
    s = DryRunSettings()
    fs, n = s.monitor_fs_Hz, 10_000
    t = np.arange(n) / fs
    env = np.clip(t / 0.2, 0, 1) * 2e-3

    def current(tt):
        return np.interp(tt, t, env) * np.sin(2 * np.pi * 1000 * tt) * (tt >= 0)
    cmd = current(t)
    measured = current(t - delay_us * 1e-6)
    onset = next(c for c in check_loopback(measured * 1000, np.full(n, 3.3), cmd, s, 3.3)
                 if c.name == "onset")
    got_ms = float(onset.figure.split()[1])
    assert got_ms == pytest.approx(delay_us / 1000, abs=0.003)
    # the same current sampled 70 us after each clock edge by a multiplexed A/D
    skewed = current(t + 70e-6 - delay_us * 1e-6)
    onset = next(c for c in check_loopback(skewed * 1000, np.full(n, 3.3), cmd, s, 3.3,
                                           monitor_delay_s=70e-6) if c.name == "onset")
    assert float(onset.figure.split()[1]) == pytest.approx(delay_us / 1000, abs=0.003)


def test_no_monitor_channel_is_refused_before_any_device(tmp_path, write_hw_config, capsys):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none")
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 2
    err = capsys.readouterr()
    assert "acquisition.monitor_channel is not set" in err.err
    assert "stimulator:" not in err.out                  # no device was touched


def test_a_leptrino_chain_has_no_monitor_input(tmp_path, write_hw_config):
    hw = write_hw_config(tmp_path / "hw.toml", kind="leptrino", speed=1.0, estop="none",
                         fs_Hz=1200.0)
    with pytest.raises(HardwareConfigError, match="acquisition.kind = 'leptrino' has none"):
        with_monitor(load_hw_config(hw))


def test_an_analog_chain_without_its_calibration_is_refused_in_one_line(tmp_path,
                                                                       write_hw_config):
    # load_hw_config always builds one for an analog chain: a configuration built in code
    # without it is refused by name, not with an AttributeError
    import dataclasses
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=7)
    cfg = dataclasses.replace(load_hw_config(hw), calibration=None)
    with pytest.raises(HardwareConfigError, match=r"hw\.toml: the analog chain has no"):
        with_monitor(cfg)


def test_a_monitor_on_a_sensor_channel_is_refused(tmp_path, write_hw_config):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", monitor=6)   # the sync's
    with pytest.raises(HardwareConfigError, match=r"acquisition\.monitor_channel.*distinct"):
        load_hw_config(hw)


def test_too_many_channels_for_the_rate_is_refused_before_stimulating(tmp_path,
                                                                     write_hw_config, capsys):
    """16 scanned channels at 10 kHz = 160 kS/s; at 10 us per channel the AI-1608AY-USB
    converts 100 kS/s (Contec: "sampling clock period error")."""
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=15)
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 2
    captured = capsys.readouterr()
    assert "needs 160 kS/s" in captured.err and "at most 100 kS/s" in captured.err
    assert "6250 Hz for 16 channels" in captured.err
    assert "dry run: 3 trial(s)" in captured.out and "record:" not in captured.out


@pytest.mark.parametrize("kw, msg", [({"amplitude_mA": 8.0}, "<= 5 mA"),
                                     ({"load_ohm": 10.0}, "100 .. 10000 Ohm"),
                                     ({"amplitude_mA": 5.0, "load_ohm": 4700.0}, "above the A/D"),
                                     ({"channel": "biceps"}, "'extensor' or 'flexor'"),
                                     ({"monitor_fs_Hz": 10_500.0}, "multiple of the 1000 Hz")])
def test_settings_are_validated(kw, msg):
    with pytest.raises(StimulatorSettingError, match=msg):
        DryRunSettings(**kw)


def test_nidaq_aggregate_rate_is_refused_before_stimulating(tmp_path, write_hw_config,
                                                             capsys):
    """32 scanned channels at 20 kHz = 640 kS/s, above the (fake) USB-6212's 400 kS/s
    multichannel rate (``Device.ai_max_multi_chan_rate``)."""
    hw = write_hw_config(tmp_path / "hw.toml", kind="nidaq", speed=1.0, estop="none",
                         monitor=31, extra=("monitor_fs_Hz = 20000.0",))
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "needs 640 kS/s" in err and "at most 400 kS/s" in err


def test_nidaq_spreads_conversions_over_the_sample_period(tmp_path, write_hw_config):
    """16 channels at 20 kHz do not fit the 80 kHz default convert clock: the conversions
    are spread over the 50 us period (320 kHz), and the dry run corrects for that delay."""
    # 16 channels are single-ended only on a USB-6212 (ai8..15 have no DIFF): RSE
    ok, text = _run(tmp_path, write_hw_config, kind="nidaq", monitor_fs_Hz=20_000.0,
                    monitor=15, extra=('nidaq.terminal_config = "RSE"',))
    assert ok, text
    assert f"scan delay {15 / 320e3 * 1e3:.3f} ms corrected" in text


def test_the_dry_run_trips_on_the_estop_mid_trial(tmp_path, write_hw_config):
    """25, 4: through run_block and the interlock; after the E-stop the resistor current is
    zero and the sync output low, recorded by the same A/D."""
    ok, text = _run(tmp_path, write_hw_config, estop_at_s=0.5)
    assert ok, text
    assert "[PASS] E-stop: trial ended: after" in text and "estop" in text
    assert "[PASS] E-stop: output zero" in text and "[PASS] E-stop: sync low" in text


def test_probe_dry_run_includes_the_estop_test(tmp_path, write_hw_config, capsys):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=1.0, estop="none",
                         monitor=7)
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "E-stop at 0.5 s (mid-chirp)" in out and "[PASS] E-stop: output zero" in out


def test_estop_checks_fail_when_output_continues():
    from nmsid.drivers.dry_run import check_after_stop
    s = DryRunSettings()
    bad = check_after_stop(np.full(100, 1.0), np.full(100, 3.3), s, has_sync=True)
    assert [c.passed for c in bad] == [False, False]
    good = check_after_stop(np.full(100, 1e-3), np.zeros(100), s, has_sync=True)
    assert [c.passed for c in good] == [True, True]
