"""Hardware configuration: the example is valid; every bad setting is named."""

from __future__ import annotations

from pathlib import Path

import pytest

from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.hw_config import load_hw_config, parse_hw_config

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "hw-config.example.toml"


def base():
    return {"stimulator": {"ceiling_ext_mA": 12.0},
            "acquisition": {"kind": "caio"},
            "sensor": {"channels": {"Fx": 0}, "rated": {"Fx": 500.0},
                       "rated_output_V": {"Fx": 10.0}, "sync_channel": 1}}


def test_example_file_is_valid():
    cfg = load_hw_config(EXAMPLE)
    assert cfg.acquisition.kind == "caio" and cfg.acquisition.fs_Hz == 2000.0
    assert cfg.calibration.n_channels == 7 and cfg.calibration.full_wrench
    assert cfg.estop.kind == "serial" and not cfg.fake


def test_minimal_config_defaults():
    cfg = parse_hw_config(base())
    assert cfg.stimulator.ceiling_ext_mA == 12.0 and cfg.stimulator.ceiling_flex_mA == 16.0
    assert cfg.calibration.n_channels == 2 and cfg.estop.kind == "none"


@pytest.mark.parametrize("patch, message", [
    ({"acquisition": {"kind": "labjack"}}, r"acquisition.kind = 'labjack'.*caio, leptrino, nidaq"),
    ({"stimulator": {"ceiling_ext_mA": -1}}, r"stimulator.ceiling_ext_mA = -1"),
    ({"stimulator": {"flexor_channel": 1}}, r"stimulator.flexor_channel.*differ"),
    ({"stimulator": {"sync_out": 0}}, r"stimulator.sync_out = 0"),
    ({"stimulator": {"ceiling": 5}}, r"unknown setting\(s\) stimulator.ceiling"),
    ({"typo": {}}, r"unknown setting\(s\) typo"),
    ({"acquisition": {"caio": {"range": "PM20"}}}, r"acquisition.caio.range = 'PM20'"),
    ({"acquisition": {"nidaq": {"terminal_config": "diff"}}}, r"terminal_config = 'diff'"),
    ({"sensor": {"channels": {"Fq": 0}}}, r"sensor.channels.Fq.*not a sensor axis"),
    ({"sensor": {"rated": {"Fx": 0.0}}}, r"axis Fx: rated and rated_output_V must both be > 0"),
    ({"sensor": {"sync_channel": 0}}, r"channels must be distinct"),
    ({"sensor": {"extension_direction": [0, 0, 0]}}, r"sensor.extension_direction"),
    ({"sensor": {"extension_direction": [0, 1, 0]}}, r"uses Fy, which is not wired"),
    ({"sensor": {"matrix": [[1.0] * 6] * 6}}, r"matrix needs all six axes"),
    ({"estop": {"kind": "serial"}}, r"estop.port"),
    ({"estop": {"kind": "serial", "port": "COM3", "line": "RI"}}, r"estop.line = 'RI'"),
    ({"rig": {"fake": "yes"}}, r"rig.fake = 'yes'.*true or false"),
])
def test_bad_settings_are_named(patch, message):
    data = base()
    for table, values in patch.items():
        if isinstance(values, dict):
            target = data.setdefault(table, {})
            for k, v in values.items():
                if isinstance(v, dict) and isinstance(target.get(k), dict):
                    target[k].update(v)
                else:
                    target[k] = v
        else:
            data[table] = values
    with pytest.raises(HardwareConfigError, match=message):
        parse_hw_config(data, "rig.toml")


def test_missing_sync_channel_is_refused():
    data = base()
    del data["sensor"]["sync_channel"]
    with pytest.raises(HardwareConfigError, match="sensor.sync_channel is missing"):
        parse_hw_config(data)


def test_leptrino_refuses_2000_Hz_with_a_clear_message():
    data = {"acquisition": {"kind": "leptrino", "fs_Hz": 2000.0,
                            "leptrino": {"port": "COM5"}}}
    with pytest.raises(HardwareConfigError, match=r"acquisition.fs_Hz = 2000.0 .*about 1200 Hz"
                                                  r".*caio.*nidaq"):
        parse_hw_config(data)
    data["acquisition"]["fs_Hz"] = 1200.0
    cfg = parse_hw_config(data)
    assert cfg.calibration is None
    data["sensor"] = {"channels": {"Fx": 0}}
    with pytest.raises(HardwareConfigError, match="sensor.channels.*only for analog chains"):
        parse_hw_config(data)


def test_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="--hw-config"):
        load_hw_config(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig\nfake = true\n")
    with pytest.raises(HardwareConfigError, match="not valid TOML"):
        load_hw_config(bad)
