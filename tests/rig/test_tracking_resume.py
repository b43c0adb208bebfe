"""Tracking sessions resume (issue 36): one that ended during calibration is named by
``recover`` and resumed to completion from the controller and targets it recorded."""

import pytest

from nmsid.analysis.control.design import design_controller
from nmsid.analysis.control.targets import Target
from nmsid.analysis.twin import Twin
from nmsid.cli import main
from nmsid.protocols.config import load_config
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import TripPolicy
from nmsid.rig.session_log import journal_dir, recover
from nmsid.rig.tracking import TrackingEngine
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.participant import default_participant

TARGET = Target("sine-1Hz", "sine", {"mean_N": 0.0, "amplitude_N": 1.5, "f_Hz": 1.0}, 2.0,
                0.5)


def _crash(self):
    raise RuntimeError("simulated crash during calibration")


def test_a_tracking_session_ended_during_calibration_resumes_to_completion(
        tmp_path, monkeypatch, capsys):
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    d.baseline["relay_s"] = 2.0
    cfg = load_config(None).with_protocol(rest_s=0.0)
    path = tmp_path / "t.h5"
    # the sim rig's participant as `nmsid run` makes it, so that the resume's rig matches
    with monkeypatch.context() as m:
        m.setattr("nmsid.rig.engine.calibrate", _crash)
        eng = TrackingEngine(cfg, make_sim_rig(default_participant(seed=7)), path, design=d,
                             targets=[TARGET], trip_policy=TripPolicy.END_SESSION,
                             extra_attrs={"rig_backend": "sim", "sim_seed": 7,
                                          "participant_model": "template"})
        with pytest.raises(RuntimeError, match="simulated crash"):
            eng.run()
    assert journal_dir(path).is_dir() and not path.exists()
    assert recover(path).action == "no-calibration"
    assert main(["run", "--backend", "sim", "--resume", str(path), "--quiet"]) == 0, \
        capsys.readouterr()
    assert validate_session(path) == [] and not journal_dir(path).exists()
    s = read_session(path)
    assert s.attrs["session_kind"] == "tracking"
    assert [t.extra_attrs["controller"] for t in s.trials] == ["relay", "twin", "baseline"]
    assert all(t.completed for t in s.trials)
    assert all(t.extra_attrs["target_json"] == TARGET.to_json() for t in s.trials[1:])
