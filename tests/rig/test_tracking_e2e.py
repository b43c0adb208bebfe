"""End to end with a participant written outside nmsid (a module in a tmp folder, loaded
from the current directory): calibration + identification session, ``identify``,
``control design``, a tracking session, ``validate``, ``control report``."""

import json
import sys
import textwrap

import pytest

from nmsid.cli import main
from nmsid.protocols.session_file import read_session, validate_session

LAB_PARTICIPANT = '''
"""A lab's elbow: two muscles, linear recruitment above a threshold, each through a
second-order lag, extensor minus flexor. Plain numpy, nothing from nmsid."""
import numpy as np


class Elbow:
    def __init__(self, seed, fs_Hz):
        self.h = 1.0 / fs_Hz
        self.wn, self.zeta = 18.0, 0.6
        self.state = np.zeros(4)     # (force, rate) per muscle

    def force_N(self, I_ext_mA, I_flex_mA):
        drive_e = 0.9 * np.clip(I_ext_mA - 1.5, 0.0, 12.0)
        drive_f = 0.8 * np.clip(I_flex_mA - 1.0, 0.0, 12.0)
        out = np.empty(len(drive_e))
        fe, ve, ff, vf = self.state
        w2, c, h = self.wn ** 2, 2 * self.zeta * self.wn, self.h
        for k in range(len(out)):        # semi-implicit Euler, state kept between calls
            ve += h * (w2 * (drive_e[k] - fe) - c * ve)
            fe += h * ve
            vf += h * (w2 * (drive_f[k] - ff) - c * vf)
            ff += h * vf
            out[k] = fe - ff
        self.state[:] = (fe, ve, ff, vf)
        return out


def make(seed, fs_Hz):
    return Elbow(seed, fs_Hz)
'''

CONFIG = """
participant = "LAB01"
[protocol]
sE_levels = [0.3, 0.45, 0.6, 0.75, 0.9]
repeats = 1
steady_s = 1.0
chirp_s = 2.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""


@pytest.fixture
def lab(tmp_path, monkeypatch):
    (tmp_path / "mylab_elbow.py").write_text(textwrap.dedent(LAB_PARTICIPANT),
                                             encoding="utf-8")
    (tmp_path / "short.toml").write_text(CONFIG, encoding="utf-8")
    (tmp_path / "target.csv").write_text(
        "t_s,force_N\n0,0\n0.5,1.0\n1.0,-0.5\n1.5,0.5\n2.0,0\n", encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    sys.modules.pop("mylab_elbow", None)


def test_plugin_participant_end_to_end(lab, capsys):
    sim = ["--backend", "sim", "--participant-model", "mylab_elbow:make",
           "--config", "short.toml", "--quiet"]
    assert main(["run", *sim, "--out", "id.h5", "--no-identify"]) == 0
    assert validate_session("id.h5") == []
    s = read_session("id.h5", load_data=False)
    assert s.attrs["participant_model"] == "mylab_elbow:make"
    assert s.calibration.Iemin_mA > 0 and len(s.trials) == 5
    assert main(["identify", "id.h5", "--out", "ana", "--no-figures"]) == 0
    assert main(["control", "design", "ana/twin.json", "--out", "ctl"]) == 0
    design = json.loads((lab / "ctl" / "controller.json").read_text())
    assert design["format"] == "nmsid-controller" and design["levels"]
    assert "| sE |" in (lab / "ctl" / "design.md").read_text()
    assert main(["run", *sim, "--track", "ctl/controller.json", "--target", "target.csv",
                 "--out", "track.h5"]) == 0
    assert main(["validate", "track.h5"]) == 0
    trials = read_session("track.h5").trials
    assert [t.extra_attrs["controller"] for t in trials] == ["relay", "twin", "baseline"]
    assert main(["control", "report", "track.h5", "--out", "rep"]) == 0
    rep = json.loads((lab / "rep" / "tracking.json").read_text())
    twin = rep["controllers"]["twin"]["rmse_pct_of_range"]
    base = rep["controllers"]["baseline"]["rmse_pct_of_range"]
    assert twin is not None and base is not None and twin < base
    assert (lab / "rep" / "figures" / "tracking-target.png").is_file()
    assert (lab / "rep" / "figures" / "tracking-target.pdf").read_bytes()[:5] == b"%PDF-"
    # nothing replaced without --force
    assert main(["control", "report", "track.h5", "--out", "rep"]) == 2
    # a glob (issue 39): the session without tracking trials is named and skipped
    capsys.readouterr()
    assert main(["control", "report", "id.h5", "track.h5", "--out", "rep2"]) == 0
    assert "id.h5: skipped: no tracking trials" in capsys.readouterr().out
    assert (lab / "rep2" / "tracking.json").is_file()
    assert main(["control", "report", "id.h5", "id.h5", "--out", "rep3"]) == 2
    assert not (lab / "rep3").exists()
    # a resume imports no plug-in its command does not name (issue 36)
    assert main(["run", "--backend", "sim", "--resume", "track.h5", "--quiet"]) == 2
    assert "--participant-model mylab_elbow:make" in capsys.readouterr().err


def test_bad_plugin_and_track_arguments_are_one_line(lab, capsys):
    sim = ["run", "--backend", "sim", "--config", "short.toml", "--quiet"]
    assert main([*sim, "--participant-model", "mylab_elbow", "--out", "a.h5"]) == 2
    assert main([*sim, "--participant-model", "nope_mod:make", "--out", "b.h5"]) == 2
    assert main([*sim, "--target", "target.csv", "--out", "c.h5"]) == 2
    assert main([*sim, "--track", "absent.json", "--out", "d.h5"]) == 2
    err = capsys.readouterr().err
    assert "package.module:factory" in err and "not found" in err
    assert "--target needs --track" in err
    assert "no such controller file" in err and "Traceback" not in err
    assert not any((lab / n).exists() for n in ("a.h5", "b.h5", "c.h5", "d.h5"))
