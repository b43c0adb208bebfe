"""nmsid design per joint (issue 41): the prior's joint decides the noise assumed, the
population drawn and the protocol file's joint."""

from __future__ import annotations

import pytest

from nmsid.analysis.design.prior import DEFAULT_NOISE_N, default_noise, population_prior
from nmsid.analysis.design.report import protocol_toml
from nmsid.cli import main


def test_the_noise_assumed_is_the_joints():
    assert default_noise("elbow") == DEFAULT_NOISE_N
    assert default_noise("knee") == pytest.approx(10 * DEFAULT_NOISE_N)   # Fmax 50 vs 5
    assert default_noise("ankle") == pytest.approx(4 * DEFAULT_NOISE_N)
    assert default_noise("a_lab_joint") == DEFAULT_NOISE_N


def test_a_population_prior_of_the_knee_is_in_n_m():
    knee, elbow = population_prior(3, seed=1, joint="knee"), population_prior(3, seed=1)
    assert knee.joint == "knee" and elbow.joint == "elbow" and "knee" in knee.source
    kp_knee = [p.parameters_at(1.0)[0] for p in knee.participants]
    kp_elbow = [p.parameters_at(1.0)[0] for p in elbow.participants]
    assert min(kp_knee) > 5 * max(kp_elbow)


def test_the_protocol_file_names_a_leg_joint():
    from nmsid.analysis.design.candidates import paper_candidate
    c = paper_candidate()
    assert 'joint = "knee"' in protocol_toml(c, joint="knee")
    assert "joint" not in protocol_toml(c)       # an elbow's file is as before


def test_an_unknown_joint_is_refused_in_one_line(tmp_path, capsys):
    code = main(["design", "--population", "--joint", "wrist", "--out", str(tmp_path / "d")])
    assert code == 2 and "--joint 'wrist'" in capsys.readouterr().err
