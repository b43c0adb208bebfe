"""The muscle form of twin.json (analysis.muscle.twin_form, analysis.twin)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.prior import twin_prior
from nmsid.analysis.errors import TwinFileError
from nmsid.analysis.muscle import literature as lit
from nmsid.analysis.muscle.dynamics import PARAM_NAMES
from nmsid.analysis.twin import Twin

BASE = {"format": "nmsid-twin", "format_version": 1, "participant": "P",
        "calibration": {"Iemin_mA": 2.0, "Iemax_mA": 9.0, "Ifmin_mA": 1.5, "Ifmax_mA": 8.0},
        "sE_range": [0.3, 1.0],
        "parameters": {"Kp": {"model": "constant", "coefficients": [2.0]},
                       "wn_rad_s": {"model": "constant", "coefficients": [20.0]},
                       "zeta": {"model": "constant", "coefficients": [0.5]}},
        "offset_N": {"model": "constant", "coefficients": [0.25]}, "effects": []}


def _muscle():
    return {"form": "hill2-isometric", "form_version": 2, "fit_fs_Hz": 100.0,
            "params": dict(zip(PARAM_NAMES, map(float, lit.start_theta()), strict=True))}


def test_version_1_items_are_read_as_version_2_with_their_meaning():
    """A version-1 item (one k_s, no threshold, no delay) simulates as the version-2 item
    with k_e = k_f = k_s and zero thresholds and delay; a version-2 item's threshold and
    delay change the force."""
    from nmsid.analysis.muscle.twin_form import V1_NAMES, parse_muscle_model, simulate_muscle
    v2 = _muscle()
    p = dict(v2["params"], k_e=0.4, k_f=0.4, th_e=0.0, th_f=0.0, delay_s=0.0)
    v1 = {"form": "hill2-isometric", "form_version": 1, "fit_fs_Hz": 100.0,
          "params": {n: (0.4 if n == "k_s" else p[n]) for n in V1_NAMES}}
    parse_muscle_model(v1, "t.json")
    rE = 0.5 + 0.4 * np.sin(2 * np.pi * 3.0 * np.arange(3000) / 1000.0)
    y1 = simulate_muscle(v1, rE, 0.8, 1000.0)
    y2 = simulate_muscle(dict(v2, params=p), rE, 0.8, 1000.0)
    assert np.array_equal(y1, y2)
    y_th = simulate_muscle(dict(v2, params=dict(p, th_e=0.2)), rE, 0.8, 1000.0)
    y_d = simulate_muscle(dict(v2, params=dict(p, delay_s=0.01)), rE, 0.8, 1000.0)
    assert np.ptp(y_th - y2) > 0.01 * np.ptp(y2)
    assert np.allclose(y_d[20:], y2[10:-10], atol=1e-9)       # a 10-sample shift
    with pytest.raises(TwinFileError, match="params.k_s"):
        parse_muscle_model(dict(v1, params=dict(v1["params"], k_s=None)), "t.json")
    with pytest.raises(TwinFileError, match="th_e"):
        parse_muscle_model(dict(v2, params=dict(p, th_e=1.5)), "t.json")


def test_existing_form_stays_valid_and_muscle_form_runs(tmp_path):
    plain = Twin.from_dict(dict(BASE))
    assert plain.muscle_model is None and "muscle_model" not in plain.to_dict()
    path = tmp_path / "twin.json"
    path.write_text(json.dumps(dict(BASE, muscle_model=_muscle())))
    tw = Twin.load(path)
    assert tw.muscle_model["form"] == "hill2-isometric"
    assert tw.to_dict()["muscle_model"]["params"] == _muscle()["params"]
    rE = 0.5 + 0.4 * np.sin(2 * np.pi * 2.0 * np.arange(4000) / 2000.0)
    f_m = tw.simulate(rE, 0.8, 2000.0)
    f_2 = plain.simulate(rE, 0.8, 2000.0)
    assert f_m.shape == rE.shape and abs(f_m[0] - 0.25) < 1e-9   # at rest: the offset
    assert np.ptp(f_m) > 0.1 and not np.allclose(f_m, f_2)


def test_a_bad_muscle_item_is_named(tmp_path):
    bad = _muscle()
    bad["params"]["tau_act_s"] = -1.0
    with pytest.raises(TwinFileError, match="muscle_model.params.tau_act_s"):
        Twin.from_dict(dict(BASE, muscle_model=bad))
    with pytest.raises(TwinFileError, match="knows 'hill2-isometric'"):
        Twin.from_dict(dict(BASE, muscle_model=dict(_muscle(), form="other")))


def test_design_refuses_the_muscle_form_in_one_line(tmp_path):
    path = tmp_path / "twin.json"
    path.write_text(json.dumps(dict(BASE, muscle_model=_muscle())))
    with pytest.raises(DesignError, match="muscle form") as exc:
        twin_prior(path, noise_N=0.03)
    assert "\n" not in str(exc.value)
