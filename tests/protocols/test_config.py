"""Configuration: defaults, TOML loading, and refusal of every kind of bad value."""

import dataclasses
import json

import pytest

from nmsid.protocols.config import (
    Config,
    ConfigError,
    PausePolicy,
    Randomisation,
    config_from_dict,
    config_from_json,
    load_config,
)


def test_defaults_are_the_papers_protocol():
    cfg = load_config()
    p = cfg.protocol
    assert p.sE_levels == tuple(round(0.30 + 0.05 * k, 2) for k in range(15))
    assert p.sE_levels[0] == 0.30 and p.sE_levels[-1] == 1.00
    assert p.repeats == 3 and p.randomisation is Randomisation.BLOCKS
    assert (p.steady_s, p.chirp_s, p.chirp_f0_Hz, p.chirp_f1_Hz) == (5, 10, 1, 10)
    assert (p.rE_centre, p.rE_amplitude, p.fs_Hz, p.carrier_Hz, p.rest_s) == (
        0.5, 0.5, 2000, 1000, 60)
    assert p.n_samples == 30000
    c = cfg.calibration
    assert (c.step_mA, c.Fmin_N, c.Fmax_N) == (0.5, 0.5, 5.0)
    assert cfg.interlock.stall_timeout_s == 0.1


def test_toml_file_and_overrides(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('participant = "P07"\nseed = 5\n[protocol]\nsE_min = 0.4\nsE_max = 0.6\n'
                 'sE_step = 0.1\nrandomisation = "full"\npause_policy = "abort"\n'
                 '[calibration.manual]\nIemin_mA = 2\nIemax_mA = 9\nIfmin_mA = 1.5\n'
                 'Ifmax_mA = 8\n[interlock]\nforce_limit_N = 12\n')
    cfg = load_config(f, overrides={"seed": 9, "participant": None})
    assert cfg.participant == "P07" and cfg.seed == 9
    assert cfg.protocol.sE_levels == (0.4, 0.5, 0.6)
    assert cfg.protocol.randomisation is Randomisation.FULL
    assert cfg.protocol.pause_policy is PausePolicy.ABORT
    assert cfg.calibration.manual.Iemax_mA == 9.0
    assert cfg.interlock.force_limit_N == 12.0


def test_json_round_trip():
    cfg = config_from_dict({"participant": "A-1", "seed": 3,
                            "protocol": {"sE_levels": [0.5, 0.7], "repeats": 2},
                            "calibration": {"manual": {"Iemin_mA": 1, "Iemax_mA": 5,
                                                       "Ifmin_mA": 1, "Ifmax_mA": 6}}})
    back = config_from_json(cfg.to_json())
    assert back.to_dict() == cfg.to_dict()
    assert json.loads(cfg.to_json())["protocol"]["randomisation"] == "blocks"


@pytest.mark.parametrize("data, setting, words", [
    ({"protocol": {"sE_levels": [0.3, 1.2]}}, "protocol.sE_levels", "(0, 1]"),
    ({"protocol": {"sE_levels": [0.0]}}, "protocol.sE_levels", "(0, 1]"),
    ({"protocol": {"chirp_f1_Hz": 1000.0}}, "protocol.chirp_f1_Hz", "Nyquist"),
    ({"protocol": {"fs_Hz": 15.0}}, "protocol.chirp_f1_Hz", "Nyquist"),
    ({"protocol": {"chirp_f1_Hz": 0.5}}, "protocol.chirp_f1_Hz", "above chirp_f0_Hz"),
    ({"participant": "Jane Doe"}, "participant", "letters, digits"),
    ({"participant": "x" * 65}, "participant", "1 to 64"),
    ({"protocol": {"repeats": 0}}, "protocol.repeats", ">= 1"),
    ({"protocol": {"rE_amplitude": 0.6}}, "protocol.rE_amplitude", "[0, 1]"),
    ({"protocol": {"randomisation": "shuffle"}}, "protocol.randomisation", "'blocks'"),
    ({"protocol": {"steady_s": "5"}}, "protocol.steady_s", "a number"),
    ({"calibration": {"Fmax_N": 0.2}}, "calibration.Fmax_N", "above Fmin_N"),
    ({"calibration": {"manual": {"Iemin_mA": 1}}}, "calibration.manual.Iemax_mA", "missing"),
    ({"calibration": {"manual": {"Iemin_mA": 5, "Iemax_mA": 4, "Ifmin_mA": 1,
                                 "Ifmax_mA": 6}}}, "calibration.manual.Iemax_mA", "above"),
    ({"calibration": {"ceiling_ext_mA": 10, "manual": {"Iemin_mA": 1, "Iemax_mA": 12,
                                                       "Ifmin_mA": 1, "Ifmax_mA": 6}}},
     "calibration.manual.Iemax_mA", "ceiling_ext_mA"),
    ({"interlock": {"stall_timeout_s": -1}}, "interlock.stall_timeout_s", "> 0"),
    ({"seed": -4}, "seed", ">= 0"),
])
def test_bad_values_are_refused_naming_the_setting(data, setting, words):
    with pytest.raises(ConfigError) as ei:
        config_from_dict(data, source="my.toml")
    e = ei.value
    assert isinstance(e, ValueError)
    assert e.setting == setting
    msg = str(e)
    assert msg.startswith("my.toml: setting " + setting) and words in msg


def test_unknown_key_lists_the_known_ones():
    with pytest.raises(ConfigError) as ei:
        config_from_dict({"protocol": {"chirp_seconds": 3}}, source="f.toml")
    msg = str(ei.value)
    assert "protocol.chirp_seconds" in msg and "chirp_s" in msg and "steady_s" in msg
    with pytest.raises(ConfigError, match="participant"):
        config_from_dict({"particpant": "P1"})


def test_bad_toml_names_the_file(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text("participant = \n")
    with pytest.raises(ConfigError, match="bad.toml"):
        load_config(f)


def test_ceiling_above_device_range_is_refused():
    cfg = config_from_dict({"calibration": {"ceiling_ext_mA": 10, "ceiling_flex_mA": 40}},
                           source="c.toml")
    cfg.check_device(50.0)
    with pytest.raises(ConfigError, match="calibration.ceiling_flex_mA.*at most 16"):
        cfg.check_device(16.0, "STG4002")


def test_config_is_frozen():
    cfg = Config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.participant = "X"  # type: ignore[misc]


def test_missing_configuration_file_is_named(tmp_path):
    from nmsid.protocols.config import load_config
    with pytest.raises(FileNotFoundError, match="nope.toml: no such configuration file"):
        load_config(tmp_path / "nope.toml")
