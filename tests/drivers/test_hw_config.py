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
    ({"acquisition": {"kind": "labjack"}},
     r"acquisition.kind = 'labjack'.*'caio', 'nidaq' or 'leptrino'"),
    ({"stimulator": {"ceiling_ext_mA": -1}}, r"stimulator.ceiling_ext_mA = -1"),
    ({"stimulator": {"flexor_channel": 1}}, r"stimulator.flexor_channel.*differ"),
    ({"stimulator": {"sync_out": 0}}, r"stimulator.sync_out = 0"),
    ({"stimulator": {"ceiling": 5}}, r"stimulator.ceiling = 5 is invalid; unknown setting"),
    ({"typo": {}}, r"typo = \{\} is invalid; unknown setting"),
    ({"acquisition": {"caio": {"range": "PM20"}}}, r"acquisition.caio.range = 'PM20'"),
    ({"acquisition": {"nidaq": {"terminal_config": "diff"}}}, r"terminal_config = 'diff'"),
    ({"sensor": {"channels": {"Fq": 0}}}, r"sensor.channels.Fq = 'Fq' is invalid; one of 'Fx'"),
    ({"sensor": {"rated": {"Fx": 0.0}}}, r"sensor.rated.Fx = 0.0 is invalid; a value > 0"),
    ({"sensor": {"sync_channel": 0}}, r"channels must be distinct"),
    ({"sensor": {"extension_direction": [0, 0, 0]}}, r"sensor.extension_direction"),
    ({"sensor": {"extension_direction": [0, 1, 0]}}, r"uses Fy, which is not wired"),
    ({"sensor": {"matrix": [[1.0] * 6] * 6}}, r"matrix needs all six axes"),
    ({"estop": {"kind": "serial"}}, r"estop.port"),
    ({"estop": {"kind": "serial", "port": "COM3", "line": "RI"}}, r"estop.line = 'RI'"),
    ({"rig": {"fake": "yes"}}, r"rig.fake = 'yes'.*true or false"),
    ({"acquisition": {"monitor_channel": 0}}, r"acquisition.monitor_channel.*distinct"),
    ({"acquisition": {"monitor_channel": 1}}, r"acquisition.monitor_channel.*distinct"),
    ({"acquisition": {"monitor_channel": 64}}, r"acquisition.monitor_channel = 64"),
    ({"acquisition": {"monitor_fs_Hz": 10_500.0}}, r"monitor_fs_Hz = 10500.0.*multiple of"),
    ({"acquisition": {"monitor_fs_Hz": 5000.0}}, r"monitor_fs_Hz = 5000.0"),
    ({"acquisition": {"caio": {"conversion_us": 0.0}}}, r"acquisition.caio.conversion_us"),
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


def test_declared_choices_match_the_drivers_tables():
    from typing import get_args

    from nmsid.drivers.analog_force import AXES
    from nmsid.drivers.caio import INPUT_METHODS, RANGES_V
    from nmsid.drivers.hw_config import Axis, CaioSettings, NidaqSettings
    from nmsid.drivers.nidaq import TERMINAL_CONFIGS
    fields = CaioSettings.__pydantic_fields__
    assert set(get_args(Axis)) == set(AXES)
    assert set(get_args(fields["range"].annotation)) == set(RANGES_V)
    assert set(get_args(fields["input_method"].annotation)) == set(INPUT_METHODS) | {""}
    assert set(get_args(NidaqSettings.__pydantic_fields__["terminal_config"].annotation)) == \
        set(TERMINAL_CONFIGS)


def test_monitor_channel_is_for_analog_chains_and_off_by_default():
    assert parse_hw_config(base()).acquisition.monitor_channel is None
    data = base()
    data["acquisition"]["monitor_channel"] = 5
    cfg = parse_hw_config(data)
    assert cfg.acquisition.monitor_channel == 5
    assert cfg.calibration.monitor_channel is None          # a session never scans it
    assert cfg.calibration.n_channels == 2
    lep = {"acquisition": {"kind": "leptrino", "fs_Hz": 1200.0, "monitor_channel": 5,
                           "leptrino": {"port": "COM5"}}}
    with pytest.raises(HardwareConfigError, match="no spare analog input"):
        parse_hw_config(lep, "rig.toml")
