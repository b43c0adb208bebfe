"""Joints are data (protocols/joints.py): the registry, the configuration's joint and its
defaults, the recorded attributes, and a lab's own joint added with one entry."""

import json

import pytest

from nmsid.protocols.config import ConfigError, config_from_dict, config_from_json, load_config
from nmsid.protocols.joints import JOINTS, Joint, joint_attrs, joint_named, recorded_quantity
from nmsid.protocols.plan import RigLimits

WRIST = Joint("wrist", "wrist extensors", "wrist flexors", "wrist extensor", "wrist flexor",
              quantity="torque", lever_arm_m=None, sign="wrist extension positive",
              posture="forearm pronated in a dynamometer cuff", limit=12.0, Fmin=0.2,
              Fmax=2.0, ceiling=4.0, sensor_range=50.0, sources=("a lab's own",))


def test_shipped_joints_and_their_units():
    assert list(JOINTS)[:3] == ["elbow", "knee", "ankle"]
    assert JOINTS["elbow"].quantity_label == "force (N)"
    assert JOINTS["knee"].quantity_label == "torque (N m)"
    assert JOINTS["ankle"].role("flex") == "dorsiflexor"
    assert JOINTS["ankle"].role("ext") == "plantarflexor"
    for j in JOINTS.values():
        assert j.sources, f"{j.name} has no source for its defaults"
        assert j.Fmin < j.Fmax < j.ceiling < j.limit <= j.sensor_range


def test_elbow_defaults_are_todays():
    c = config_from_dict({})
    assert c.joint == "elbow"
    assert (c.interlock.force_limit_N, c.calibration.Fmin_N, c.calibration.Fmax_N,
            c.calibration.force_ceiling_N) == (25.0, 0.5, 5.0, 10.0)
    assert "joint" not in c.to_dict()   # older readers refuse an unknown key


@pytest.mark.parametrize("name", ["knee", "ankle"])
def test_a_joint_brings_its_limit_and_calibration(name):
    j = JOINTS[name]
    c = config_from_dict({"joint": name})
    assert c.joint_def is j
    assert c.interlock.force_limit_N == j.limit
    assert (c.calibration.Fmin_N, c.calibration.Fmax_N, c.calibration.force_ceiling_N) == (
        j.Fmin, j.Fmax, j.ceiling)
    assert RigLimits.of(c).force_limit_N == j.limit
    back = config_from_json(c.to_json())
    assert back.joint == name and back.interlock == c.interlock


def test_a_file_value_wins_over_the_joint_default(tmp_path):
    f = tmp_path / "knee.toml"
    f.write_text('joint = "knee"\n[interlock]\nforce_limit_N = 90.0\n'
                 '[calibration]\nFmax_N = 40.0\n')
    c = load_config(f)
    assert c.interlock.force_limit_N == 90.0
    assert c.calibration.Fmax_N == 40.0 and c.calibration.Fmin_N == JOINTS["knee"].Fmin


def test_overrides_joint_from_the_command_line():
    c = load_config(None, overrides={"joint": "ankle"})
    assert c.interlock.force_limit_N == JOINTS["ankle"].limit


@pytest.mark.parametrize("bad", ["hip", 3, "", "Knee"])
def test_unknown_joint_one_line(bad):
    with pytest.raises(ConfigError) as e:
        config_from_dict({"joint": bad})
    msg = str(e.value)
    assert "\n" not in msg and "joint" in msg and "'knee'" in msg


def test_a_lab_adds_a_joint_with_one_entry(monkeypatch):
    monkeypatch.setitem(JOINTS, "wrist", WRIST)
    c = config_from_dict({"joint": "wrist"})
    assert c.interlock.force_limit_N == 12.0 and c.calibration.Fmax_N == 2.0
    assert c.joint_def.quantity_label == "torque (N m)"
    assert joint_named("wrist") is WRIST


def test_recorded_attributes_and_the_elbow_fallback():
    attrs = joint_attrs(JOINTS["knee"])
    assert attrs["joint"] == "knee" and attrs["measured_unit"] == "N m"
    assert json.loads(attrs["joint_json"])["flexor_muscles"] == "hamstrings"
    assert recorded_quantity(attrs) == ("knee", "torque", "N m")
    assert recorded_quantity({}) == ("elbow", "force", "N")   # a file of today
    assert recorded_quantity({"measured_quantity": "voltage"})[1:] == ("force", "N")


@pytest.mark.parametrize("change, words", [
    ({"quantity": "power"}, "quantity"),
    ({"lever_arm_m": 0.3}, "lever_arm_m"),
    ({"Fmax": 0.1}, "Fmin < Fmax"),
    ({"limit": 60.0}, "limit <= sensor_range"),
    ({"name": "Wrist joint"}, "must match"),
    ({"flexor_channel": 1}, "channels"),
])
def test_a_bad_joint_entry_is_refused(change, words):
    from dataclasses import replace
    with pytest.raises(ValueError, match=words):
        replace(WRIST, **change)


def test_preflight_holds_targets_to_the_joints_limit_in_its_unit():
    from nmsid.protocols.plan import Plan, PlanItem, PlanRefused, preflight
    limits = RigLimits.of(config_from_dict({"joint": "knee"}))
    ok = Plan("tracking", (PlanItem(0, "tracking", 0.5, 10.0, target_range_N=(-140, 140)),))
    preflight(ok, limits)           # 140 N m is inside the knee's 150 N m
    bad = Plan("tracking", (PlanItem(0, "tracking", 0.5, 10.0, target_range_N=(0, 160)),))
    with pytest.raises(PlanRefused, match=r"torque target range .* N m .*150\] N m"):
        preflight(bad, limits)
    with pytest.raises(PlanRefused, match=r"\[-25, 25\] N"):   # the elbow's: 160 N refused
        preflight(bad, RigLimits.of(config_from_dict({})))


def test_preflight_names_the_joints_channel_roles():
    from dataclasses import replace

    from nmsid.protocols.plan import Plan, PlanItem, PlanRefused, preflight
    from nmsid.protocols.session_model import Calibration
    limits = replace(RigLimits.of(config_from_dict({"joint": "ankle"})), ceiling_ext_mA=4.0)
    plan = Plan("identification", (PlanItem(0, "identification", 1.0, 15.0),))
    with pytest.raises(PlanRefused, match="plantarflexor current"):
        preflight(plan, limits, Calibration(2.0, 9.5, 1.5, 8.0))


def test_a_limit_above_the_joints_sensor_needs_the_confirmation(monkeypatch):
    # the wrist's dynamometer reads 50 N m: a 60 N m limit could never trip
    monkeypatch.setitem(JOINTS, "wrist", WRIST)
    with pytest.raises(ConfigError, match=r"interlock.force_limit_N = 60.*wrist sensor's "
                                          r"range \(50 N m\)"):
        config_from_dict({"joint": "wrist", "interlock": {"force_limit_N": 60.0}})
    c = config_from_dict({"joint": "wrist", "interlock": {
        "force_limit_N": 60.0, "confirm_weakened_safety": True}})
    assert any("wrist sensor's range" in w for w in c.weakened_safety())
    assert config_from_dict({"joint": "wrist"}).weakened_safety() == []
