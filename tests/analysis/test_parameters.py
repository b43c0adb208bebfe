"""The shared read-only parameter mapping (issue 30, 3)."""

import json

import pytest

from nmsid.analysis.parameters import Parameters


def test_parameters_read_like_a_dict_and_keep_their_order():
    p = Parameters.of({"tau_s": 0.03, "L_s": 0.02})
    assert list(p) == ["tau_s", "L_s"] and p["L_s"] == 0.02 and p.get("x") is None
    assert p == {"L_s": 0.02, "tau_s": 0.03} and dict(p) == p.to_dict()
    assert json.dumps(p.to_dict()) == '{"tau_s": 0.03, "L_s": 0.02}'
    with pytest.raises(KeyError):
        p["zeta"]


def test_parameters_cannot_be_changed_in_place_and_a_copy_is_free():
    p = Parameters.of({"L_s": 0.02})
    with pytest.raises(TypeError):
        p["L_s"] = 0.5  # type: ignore[index]
    q = p.to_dict()
    q["L_s"] = 0.5
    assert p["L_s"] == 0.02


def test_repeated_names_are_refused():
    with pytest.raises(ValueError, match="repeat"):
        Parameters((("L_s", 0.1), ("L_s", 0.2)))
