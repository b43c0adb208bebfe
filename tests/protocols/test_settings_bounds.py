"""Each physical bound and cross-field rule of the protocol settings, and the weakened-safety
rule."""

from __future__ import annotations

import pytest

from nmsid.protocols.config import (
    FORCE_SENSOR_RANGE_N,
    MAX_LEVELS,
    SEED_MAX,
    ConfigError,
    ProtocolConfig,
    config_from_dict,
    load_config,
)


@pytest.mark.parametrize("data, setting, words", [
    ({"calibration": {"hold_s": 1e5}}, "calibration.hold_s", "<= 10"),
    ({"calibration": {"step_mA": 1e-7}}, "calibration.step_mA", ">= 0.01"),
    ({"calibration": {"step_mA": 0.01, "ceiling_ext_mA": 100.0}}, "calibration.step_mA",
     "at most 2000 steps"),
    ({"protocol": {"sE_step": 1e-9}}, "protocol.sE_step", f"at most {MAX_LEVELS} levels"),
    ({"protocol": {"sE_levels": [round(0.001 * k, 3) for k in range(1, 201)]}},
     "protocol.sE_levels", "at most 100 entries"),
    ({"protocol": {"sE_levels": [0.5], "repeats": 100, "rest_s": 0.0,
                   "chirp_s": 1000.0}}, "protocol.rest_s", "at most 12 h"),
    ({"protocol": {"fs_Hz": 1e8}}, "protocol.fs_Hz", "<= 100000"),
    ({"protocol": {"fs_Hz": 0.0}}, "protocol.fs_Hz", ">= 10"),
    ({"protocol": {"fs_Hz": 100000.0, "chirp_s": 3600.0}}, "protocol.fs_Hz",
     "samples per trial"),
    ({"protocol": {"sE_min": 0.5, "sE_max": 0.4}}, "protocol.sE_max", "[sE_min, 1]"),
    ({"protocol": {"sE_min": 0.5, "sE_levels": [0.5]}}, "protocol.sE_levels", "not both"),
    ({"protocol": {"sE_levels": [0.5, 0.5]}}, "protocol.sE_levels", "each sE level once"),
    ({"protocol": {"input_kind": "multisine", "multisine_tones": 200}},
     "protocol.multisine_tones", "at most"),
    ({"seed": 2 ** 63}, "seed", f"<= {SEED_MAX}"),
    ({"participant": "P01\n"}, "participant", "no spaces or control characters"),
    ({"participant": {"code": "P01", "colour": 1}}, "participant.colour", "unknown"),
    ({"participant": {"model": "robot"}}, "participant.model", "'template'"),
    ({"calibration": {"ceiling_ext_mA": 100.5}}, "calibration.ceiling_ext_mA", "<= 100"),
    ({"calibration": {"manual": {"Iemin_mA": 1, "Iemax_mA": 100, "Ifmin_mA": 1,
                                 "Ifmax_mA": 6}}}, "calibration.manual.Iemax_mA",
     "ceiling_ext_mA"),
    ({"calibration": {"force_ceiling_N": 4.0}}, "calibration.force_ceiling_N", "above Fmax_N"),
    ({"interlock": {"force_limit_N": 1e9}}, "interlock.force_limit_N", "typo"),
    ({"interlock": {"force_limit_N": 600.0}}, "interlock.force_limit_N",
     "--allow-weakened-safety"),
    ({"interlock": {"trip_on_sensor_fault": False}}, "interlock.trip_on_sensor_fault",
     "confirm_weakened_safety = true"),
    ({"interlock": {"estop_poll_Hz": 10.0}}, "interlock.estop_poll_Hz", "within 10 ms"),
])
def test_bound_refused_with_limit_and_reason(data, setting, words):
    with pytest.raises(ConfigError) as ei:
        config_from_dict(data, source="lab.toml")
    assert ei.value.setting == setting
    msg = str(ei.value)
    assert msg.startswith(f"lab.toml: setting {setting} = ") and words in msg, msg
    assert "\n" not in msg


def test_weakened_safety_confirmed_in_file_or_by_flag(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("[interlock]\ntrip_on_overrun = false\nforce_limit_N = 800.0\n")
    with pytest.raises(ConfigError, match="trip_on_overrun"):
        load_config(f)
    cfg = load_config(f, overrides={"confirm_weakened_safety": True})
    assert cfg.weakened_safety() == [
        "interlock.trip_on_overrun = false (that interlock rule never trips)",
        f"interlock.force_limit_N = 800 (above the force sensor's range, "
        f"{FORCE_SENSOR_RANGE_N:g} N: it can never trip)"]
    assert '"confirm_weakened_safety": true' in cfg.to_json()
    f.write_text("[interlock]\ntrip_on_overrun = false\nconfirm_weakened_safety = true\n")
    assert load_config(f).interlock.trip_on_overrun is False
    assert load_config().weakened_safety() == []
    assert "confirm_weakened_safety" not in load_config().to_json()   # older readers


def test_objects_built_in_code_fail_the_same_way():
    with pytest.raises(ConfigError) as ei:
        ProtocolConfig(fs_Hz=-1.0)
    assert ei.value.setting == "protocol.fs_Hz" and ei.value.source == "(in code)"
    cfg = load_config()
    with pytest.raises(ConfigError) as ei:
        cfg.with_protocol(repeats=0)
    assert ei.value.setting == "protocol.repeats"
    with pytest.raises(ConfigError) as ei:
        cfg.replace(seed=-1)
    assert ei.value.setting == "seed"
