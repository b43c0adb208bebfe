"""The ``[participant]`` table: participant code and simulated participant model."""

import pytest

from nmsid.protocols.config import (
    PARTICIPANT_MODELS,
    config_from_dict,
    config_from_json,
    load_config,
)
from nmsid.protocols.errors import ConfigError


def test_default_is_the_template_and_the_string_form_still_works():
    cfg = config_from_dict({"participant": "P07"})
    assert cfg.participant == "P07" and cfg.participant_model == "template"
    assert cfg.to_dict()["participant"] == "P07"       # stored as before
    assert "participant_model" not in cfg.to_dict()


@pytest.mark.parametrize("model", PARTICIPANT_MODELS)
def test_table_form_round_trips(model):
    cfg = config_from_dict({"participant": {"code": "A1", "model": model}})
    assert (cfg.participant, cfg.participant_model) == ("A1", model)
    back = config_from_json(cfg.to_json())
    assert back == cfg.replace(source=back.source)


def test_toml_table_and_code_override(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[participant]\ncode = "X9"\nmodel = "musculoskeletal"\n')
    cfg = load_config(f)
    assert (cfg.participant, cfg.participant_model) == ("X9", "musculoskeletal")
    cfg = load_config(f, overrides={"participant": "Y2"})
    assert (cfg.participant, cfg.participant_model) == ("Y2", "musculoskeletal")
    f.write_text('[participant]\nmodel = "musculoskeletal"\n')
    assert load_config(f).participant == "P01"


@pytest.mark.parametrize("table, setting, words", [
    ({"model": "opensim"}, "participant.model", "'template', 'musculoskeletal'"),
    ({"modle": "template"}, "participant.modle", "known settings here are: code, model"),
    ({"code": "Jane Doe"}, "participant", "letters, digits"),
])
def test_bad_table_names_the_setting_and_what_is_valid(table, setting, words):
    with pytest.raises(ConfigError) as exc:
        config_from_dict({"participant": table}, source="x.toml")
    msg = str(exc.value)
    assert setting in msg and words in msg and "x.toml" in msg
