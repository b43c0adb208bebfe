"""A study of sessions of several joints (issue 41): the group analysis (the paper's
Tables 1-9) is split per joint, said in one line; a study of one leg joint labels its
tables in N m. Synthetic sessions with known parameters (nmsid.testing.sessions)."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("distributed")

from nmsid.protocols.joints import JOINTS, joint_attrs  # noqa: E402
from nmsid.study.config import load_study  # noqa: E402
from nmsid.study.runner import run_study  # noqa: E402
from nmsid.testing.sessions import write_synthetic_session  # noqa: E402

LEVELS = (0.3, 0.45, 0.6, 0.75, 0.9)
STUDY = 'sessions = ["*.h5"]\n[settings]\ngap = false\nfigures = false\n'


def _sessions(folder, joints):
    for i, joint in enumerate(joints):
        k = 1.0 if joint == "elbow" else 10.0         # N m at the knee: ten times the gain
        params = {s: (k * (2.0 + 6.0 * s), 20.0 + 5.0 * s, 0.6 + 0.2 * s) for s in LEVELS}
        write_synthetic_session(folder / f"{joint}{i}.h5", seed=20 + i,
                                participant=f"P{i}", sE_levels=LEVELS, repeats=2,
                                fs_Hz=1000.0, steady_s=2.0, chirp_s=4.0, params=params,
                                noise_sd_N=0.03 * k, mains_N=0.01 * k,
                                extra_attrs=None if joint == "elbow"
                                else joint_attrs(JOINTS[joint]))
    (folder / "STUDY.toml").write_text(STUDY, encoding="utf-8")
    return load_study(folder / "STUDY.toml")


def test_sessions_of_two_joints_are_grouped_per_joint(tmp_path):
    d = tmp_path / "s"
    d.mkdir()
    cfg = _sessions(d, ["elbow", "elbow", "knee", "knee"])
    lines: list[str] = []
    out = run_study(cfg, tmp_path / "o", workers=0, progress=lines.append)
    notes = [line for line in lines if "split per joint" in line]
    assert len(notes) == 1 and "elbow: 2 in N" in notes[0] and "knee: 2 in N m" in notes[0]
    assert out.group.selection is None and set(out.group.joints) == {"elbow", "knee"}
    for joint, unit in (("elbow", "N"), ("knee", "N m")):
        g = out.group.joints[joint]
        assert sorted(g.selection.participants) == (["P0", "P1"] if joint == "elbow"
                                                    else ["P2", "P3"])
        sel = json.loads((tmp_path / "o" / f"group-{joint}" / "model_selection.json")
                         .read_text())
        assert (sel["joint"], sel["measured_unit"]) == (joint, unit)
        assert f"Kp ({unit})" in (tmp_path / "o" / f"group-{joint}" / "tables.txt").read_text()
    assert not (tmp_path / "o" / "model_selection.json").exists()   # no pooled AICc sums
    html = (tmp_path / "o" / "report.html").read_text()
    assert "split per joint" in html and "knee: Tables 1-9 (Kp in N m)" in html


def test_a_study_of_one_leg_joint_is_labelled_in_its_unit(tmp_path):
    d = tmp_path / "s"
    d.mkdir()
    out = run_study(_sessions(d, ["knee", "knee"]), tmp_path / "o", workers=0,
                    progress=None)
    assert out.group.selection is not None and not out.group.joints and not out.group.note
    assert "Kp (N m)" in (tmp_path / "o" / "tables.txt").read_text()
    sel = json.loads((tmp_path / "o" / "model_selection.json").read_text())
    assert sel["measured_unit"] == "N m"


def test_identify_refuses_to_pool_two_joints_in_one_line(tmp_path, capsys):
    from nmsid.cli import main
    d = tmp_path / "s"
    d.mkdir()
    _sessions(d, ["elbow", "knee"])
    code = main(["identify", str(d / "elbow0.h5"), str(d / "knee1.h5"), "--out",
                 str(tmp_path / "id"), "--no-figures"])
    err = capsys.readouterr()
    text = err.out + err.err
    assert code == 2 and "different joints" in text and "knee torque in N m" in text
    assert not (tmp_path / "id").exists()
