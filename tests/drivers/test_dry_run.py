"""``nmsid probe --dry-run`` end to end on the fake rig (fake STG -> simulated resistor ->
simulated A/D input), and the checks failing when the loop-back does not match."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.drivers.dry_run import DryRunSettings, check_loopback, run_dry_run
from nmsid.drivers.errors import StimulatorSettingError
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.hardware import make_hw_rig
from nmsid.cli import main


def test_probe_dry_run_passes_every_check_on_the_fake_rig(tmp_path, write_hw_config, capsys):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=4.0, estop="none")
    assert main(["probe", "--hw-config", str(hw), "--dry-run"]) == 0
    out = capsys.readouterr().out
    for name in ("onset", "force record", "amplitude", "carrier", "envelope",
                 "charge balance"):
        assert f"[PASS] {name}:" in out
    assert "[FAIL]" not in out and "dry run: OK" in out
    assert "1000.00 Hz" in out


def _run(tmp_path, write_hw_config, **loopback):
    hw = write_hw_config(tmp_path / "hw.toml", kind="caio", speed=4.0, estop="none")
    devices = make_hw_rig(hw)
    lines: list[str] = []
    try:
        devices.stimulator.connect()
        rec = load_fake("loopback").BenchLoopback(devices.clock.bench, sync_out=0,
                                                  load_ohm=1000.0, **loopback)
        ok = run_dry_run(devices, DryRunSettings(), rec, out=lines.append)
    finally:
        devices.close()
    return ok, "\n".join(lines)


def test_a_wrong_resistor_fails_the_amplitude_check(tmp_path, write_hw_config):
    ok, text = _run(tmp_path, write_hw_config, channel=0, actual_ohm=1500.0)
    assert not ok
    assert "[FAIL] amplitude: max error 1.000 mA (50.0 % of 2 mA)" in text
    assert "[PASS] carrier" in text and "[PASS] envelope" in text


def test_the_monitor_on_the_wrong_channel_fails(tmp_path, write_hw_config):
    ok, text = _run(tmp_path, write_hw_config, channel=1)   # flexor output: 0 mA
    assert not ok and "[FAIL] amplitude" in text and "[FAIL] envelope" in text


def test_unbalanced_or_late_current_is_caught():
    s = DryRunSettings()
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


@pytest.mark.parametrize("kw, msg", [({"amplitude_mA": 8.0}, "<= 5 mA"),
                                     ({"load_ohm": 10.0}, "100 .. 10000 Ohm"),
                                     ({"amplitude_mA": 5.0, "load_ohm": 4700.0}, "above the A/D"),
                                     ({"channel": "biceps"}, "'extensor' or 'flexor'")])
def test_settings_are_validated(kw, msg):
    with pytest.raises(StimulatorSettingError, match=msg):
        DryRunSettings(**kw)
