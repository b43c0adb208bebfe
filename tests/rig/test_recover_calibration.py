"""A journal whose calibration.npz cannot be read (issue 36): ``recover`` names it, keeps
it aside and takes the calibration from the published file; the session then resumes."""

import pytest

from nmsid.protocols.config import load_config
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine, TripPolicy
from nmsid.rig.session_log import journal_dir, recover
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.participant import default_participant

CONFIG = """
participant = "R01"
seed = 4
[protocol]
sE_levels = [0.4, 0.7]
repeats = 1
steady_s = 0.4
chirp_s = 0.6
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""


def _crash(self):
    """The program dies after the first trial (the journal stays, as after a crash)."""
    raise RuntimeError("simulated crash")


def test_a_damaged_journal_calibration_is_named_and_taken_from_the_file(tmp_path,
                                                                         monkeypatch):
    (tmp_path / "r.toml").write_text(CONFIG, encoding="utf-8")
    cfg = load_config(tmp_path / "r.toml").with_protocol(rest_s=0.0)
    path = tmp_path / "r.h5"
    with monkeypatch.context() as m:
        m.setattr(Engine, "_rest", _crash)
        with pytest.raises(RuntimeError, match="simulated crash"):
            Engine(cfg, make_sim_rig(default_participant(seed=1)), path,
                   trip_policy=TripPolicy.END_SESSION).run()
    jdir = journal_dir(path)
    cal_file = jdir / "calibration.npz"
    assert cal_file.exists() and path.exists()
    published = read_session(path, load_data=False).calibration
    cal_file.write_bytes(b"not a zip archive")
    rep = recover(path)
    text = rep.summary()
    assert "calibration.npz could not be read" in text and "taken from the session file" in text
    assert list(jdir.glob("calibration.npz.damaged*")) or list(jdir.glob("calibration*damaged*"))
    assert validate_session(path) == []
    summary = Engine(None, make_sim_rig(default_participant(seed=1)), path, resume=True,
                     trip_policy=TripPolicy.END_SESSION).run()
    assert summary.n_completed >= 1 and summary.n_pending == 0
    s = read_session(path)
    assert s.calibration.Iemax_mA == published.Iemax_mA
    assert sum(t.completed for t in s.trials) == 2 and validate_session(path) == []
