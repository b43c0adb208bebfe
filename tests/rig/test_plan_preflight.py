"""Plans and their preflight (issue 36): every tracking input is read and checked in full
before anything stimulates; a refusal is one line naming the file, the item, the value and
what is allowed; a streamed controller never commands above a calibrated maximum."""

import json
import math
import os

import numpy as np
import pytest

from nmsid.analysis.control.design import design_controller
from nmsid.analysis.control.errors import ControllerFileError
from nmsid.analysis.control.targets import Target
from nmsid.analysis.twin import Twin
from nmsid.cli import main
from nmsid.protocols.config import load_config
from nmsid.protocols.plan import (
    MAX_ITEM_S,
    Plan,
    PlanItem,
    PlanRefused,
    RigLimits,
    identification_plan,
    preflight,
)
from nmsid.protocols.schedule import make_schedule
from nmsid.protocols.session_file import Calibration
from nmsid.rig.engine import TripPolicy
from nmsid.rig.session_log import journal_dir
from nmsid.rig.tracking import TrackingEngine, TrackingStream
from nmsid.sim_backends import make_sim_rig
from nmsid.sim_backends.participant import default_participant

CAL = Calibration(2.0, 9.5, 1.5, 8.0, 0.5, 5.0)
LIMITS = RigLimits(ceiling_ext_mA=16.0, ceiling_flex_mA=16.0, force_limit_N=25.0)
SHORT = [Target("sine-1Hz", "sine", {"mean_N": 0.0, "amplitude_N": 1.5, "f_Hz": 1.0},
                2.0, 0.5)]
CONFIG = """
participant = "K02"
seed = 5
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""


@pytest.fixture(scope="module")
def design():
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    d.baseline["relay_s"] = 2.0
    return d


def _controller_file(tmp_path, design, **changes):
    d = design.to_dict()
    d.update(changes)
    p = tmp_path / "controller.json"
    p.write_text(json.dumps(d), encoding="utf-8")   # NaN written as the JSON extension NaN
    return p


def _run_cli(tmp_path, capsys, *extra):
    (tmp_path / "k.toml").write_text(CONFIG, encoding="utf-8")
    out = tmp_path / "t.h5"
    code = main(["run", "--backend", "sim", "--config", str(tmp_path / "k.toml"), "--out",
                 str(out), "--no-identify", *map(str, extra)])
    cap = capsys.readouterr()
    return code, cap.out, cap.err, out


# -- the cases of the issue, through the command line ------------------------------------
def test_a_controller_with_sE_2_is_refused_before_anything_stimulates(tmp_path, design,
                                                                      capsys):
    ctl = _controller_file(tmp_path, design, sE=2.0)
    code, out, err, path = _run_cli(tmp_path, capsys, "--track", ctl)
    assert code == 2, out + err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(ctl) in lines[0] and "sE = 2" in lines[0] \
        and "(0, 1]" in lines[0] and "item 0" in lines[0]
    assert not path.exists() and not journal_dir(path).exists()


def test_a_nan_force_range_is_refused_naming_it(tmp_path, design, capsys):
    ctl = _controller_file(tmp_path, design, force_range_N=[math.nan, 1.0])
    code, out, err, path = _run_cli(tmp_path, capsys, "--track", ctl)
    assert code == 2 and "force_range_N" in err and str(ctl) in err
    assert len(err.strip().splitlines()) == 1 and not path.exists()


def test_a_target_of_1e9_seconds_is_refused_before_anything_stimulates(tmp_path, design,
                                                                       capsys):
    ctl = _controller_file(tmp_path, design)
    csv = tmp_path / "long.csv"
    csv.write_text("t_s,force_N\n0,0\n1e9,1\n", encoding="utf-8")
    code, out, err, path = _run_cli(tmp_path, capsys, "--track", ctl, "--target", csv)
    assert code == 2 and str(csv) in err and "duration" in err \
        and f"(0, {MAX_ITEM_S:g}]" in err, err
    assert len(err.strip().splitlines()) == 1 and not path.exists()


def test_a_target_beyond_the_force_limit_is_refused(tmp_path, design, capsys):
    ctl = _controller_file(tmp_path, design)
    csv = tmp_path / "far.csv"
    csv.write_text("t_s,force_N\n0,0\n1,400\n", encoding="utf-8")
    code, out, err, path = _run_cli(tmp_path, capsys, "--track", ctl, "--target", csv)
    assert code == 2 and str(csv) in err and "force target range" in err \
        and "25" in err, err
    assert not path.exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs are POSIX")
@pytest.mark.timeout(60)
def test_a_fifo_as_target_or_controller_is_refused_without_reading(tmp_path, design):
    from nmsid.rig.tracking import tracking_engine
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    ctl = _controller_file(tmp_path, design)

    class Args:
        track, target, resume = str(ctl), str(fifo), None
    with pytest.raises(ControllerFileError, match="not a regular file"):
        tracking_engine(Args)
    Args.track, Args.target = str(fifo), None
    with pytest.raises(ControllerFileError, match="not a regular file"):
        tracking_engine(Args)


def test_the_engine_refuses_a_bad_tracking_plan_with_no_output(tmp_path, design):
    import dataclasses
    rig = make_sim_rig(default_participant(seed=2))
    cfg = load_config(None).with_protocol(rest_s=0.0)
    bad = dataclasses.replace(design, sE=1.5)
    with pytest.raises(PlanRefused, match=r"sE = 1.5 is outside \(0, 1\]"):
        TrackingEngine(cfg, rig, tmp_path / "t.h5", design=bad, targets=SHORT,
                       trip_policy=TripPolicy.END_SESSION, design_source="c.json")
    assert rig.world.max_sent_mA == [0.0, 0.0] and not (tmp_path / "t.h5").exists()


# -- the stream is clamped at each calibrated maximum, by construction -------------------
class _Const:
    name = "const"
    queue = 1

    def __init__(self, rE):
        self.rE = rE

    def start(self, target, target_id=""):
        return [self.rE]

    def step(self, j, y):
        return self.rE


@pytest.mark.parametrize("rE", [0.0, 0.3, 1.0])
def test_a_stream_never_exceeds_a_calibrated_maximum_even_at_sE_2(rE):
    s = TrackingStream(_Const(rE), np.zeros(4), "", 2.0, CAL, (16.0, 16.0), 200.0, 2000.0,
                       1, clock=None)
    _, Ie, If = s.currents(rE)
    assert Ie <= CAL.Iemax_mA and If <= CAL.Ifmax_mA


# -- the plan itself ---------------------------------------------------------------------
def test_a_plan_lists_without_hardware_and_states_its_envelope():
    cfg = load_config(None)
    p = cfg.protocol
    sched = make_schedule(p.sE_levels, p.repeats, p.randomisation, 1)
    plan = identification_plan(sched, p, source="cfg.toml")
    items = list(plan)
    assert len(items) == len(sched) == p.n_trials
    assert all(it.kind == "identification" and 0 < it.sE <= 1 for it in items)
    assert all(it.duration_s == p.trial_s for it in items)
    preflight(plan, RigLimits.of(cfg), CAL)
    top = max(items, key=lambda it: it.sE)
    Ie, If = top.max_current_mA(CAL)
    assert Ie <= CAL.Iemax_mA + 1e-12 and If <= CAL.Ifmax_mA + 1e-12
    assert "items" in repr(plan) and len(repr(plan)) < 100


@pytest.mark.parametrize("item, words", [
    (PlanItem(3, "tracking", 0.5, 5.0, rE_range=(-0.1, 1.0), source="a.json"),
     ("a.json: item 3", "rE range")),
    (PlanItem(0, "tracking", 0.5, math.inf), ("duration inf",)),
    (PlanItem(0, "tracking", 0.5, 5.0, target_range_N=(0.0, math.nan)),
     ("force target range",)),
    (PlanItem(0, "walking", 0.5, 5.0), ("kind 'walking'",)),
    (PlanItem(0, "identification", 0.0, 5.0), ("sE = 0.0",)),
])
def test_each_bad_item_is_refused_in_one_line(item, words):
    with pytest.raises(PlanRefused) as exc:
        preflight(Plan("test", (item,)), LIMITS)
    text = str(exc.value)
    assert "\n" not in text and all(w in text for w in words), text


def test_after_calibration_an_item_above_a_ceiling_is_refused():
    item = PlanItem(0, "identification", 1.0, 5.0)   # extensor up to Iemax = 9.5 mA
    preflight(Plan("t", (item,)), LIMITS, CAL)
    low = RigLimits(ceiling_ext_mA=9.0, ceiling_flex_mA=16.0, force_limit_N=25.0)
    with pytest.raises(PlanRefused, match="extensor current up to 9.5 mA is above 9 mA"):
        preflight(Plan("t", (item,)), low, CAL)
    with pytest.raises(PlanRefused, match="no trial was run"):
        preflight(Plan("t", (item,)), LIMITS._replace(device_max_mA=8.0)
                  if hasattr(LIMITS, "_replace") else
                  RigLimits(16.0, 16.0, 25.0, device_max_mA=8.0), CAL)
