"""Individual panels: what they show and what they refuse."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.protocols.session_file import Calibration, SessionWriter, Trial
from nmsid.rig.observer import rerun_wait_reason


# -- setup panel: the output file ----------------------------------------------------------
def _session(path, n_completed, n_planned, journal=False):
    w = SessionWriter.create(path, "S01", extra_attrs={"schedule_json": json.dumps(
        [{"index": i, "sE": 0.5, "repeat": i + 1} for i in range(n_planned)])})
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0))
    for i in range(n_completed):
        w.append_trial(Trial(sE=0.5, repeat=i + 1, fs_Hz=2000.0, rE=np.zeros(4),
                             I_ext_mA=np.zeros(4), I_flex_mA=np.zeros(4), force_N=np.zeros(4),
                             extra_attrs={"schedule_index": i}))
    if journal:
        (path.parent / (path.name + ".journal")).mkdir()


def test_check_output_new_unfinished_finished_invalid(tmp_path):
    from nmsid.rig.gui.setup_panel import OutputState, check_output
    assert check_output(tmp_path / "new.h5").state is OutputState.NEW
    _session(tmp_path / "part.h5", 1, 3)
    c = check_output(tmp_path / "part.h5")
    assert (c.state, c.n_completed, c.n_planned) == (OutputState.UNFINISHED, 1, 3)
    _session(tmp_path / "done.h5", 3, 3)
    assert check_output(tmp_path / "done.h5").state is OutputState.FINISHED
    _session(tmp_path / "crashed.h5", 3, 3, journal=True)  # journal left: not finished
    assert check_output(tmp_path / "crashed.h5").state is OutputState.UNFINISHED
    (tmp_path / "only.h5.journal").mkdir()
    assert check_output(tmp_path / "only.h5").state is OutputState.UNFINISHED
    (tmp_path / "x.h5").write_bytes(b"nope")
    assert check_output(tmp_path / "x.h5").state is OutputState.INVALID


def test_setup_panel_refuses_bad_participant_code(qtbot, tmp_path):
    from nmsid.rig.gui.setup_panel import SetupPanel
    got = []
    p = SetupPanel(on_start=got.append)
    qtbot.addWidget(p)
    p.set_values(participant="Jane Doe", output=tmp_path / "a.h5")
    assert not p.start_button.isEnabled()
    assert "not valid" in p.message.text()
    p.set_values(participant="P02")
    assert p.start_button.isEnabled()
    p.start_button.click()
    assert got and got[0].participant == "P02" and not got[0].resume


# -- safety panel --------------------------------------------------------------------------
def test_lights_follow_the_engines_rule_names(qtbot):
    from nmsid.rig.gui.safety_panel import SafetyPanel
    p = SafetyPanel(on_estop=lambda: None, on_rearm=lambda: None)
    qtbot.addWidget(p)
    p.set_interlock({"force_limit": (True, "ok"), "sensor_stream": (True, "ok"),
                     "acquisition": (False, "over-range flag"), "stimulator": (True, "ok"),
                     "estop": (True, "ok"), "latch": (False, "latched by acquisition")})
    s = p.light_states()
    assert s["Sensor stream"] is False  # acquisition flags share the sensor-stream light
    assert s["Force limit"] is True and s["Stimulator"] is True and s["E-stop"] is True
    assert s["Interlock latch"] is False
    assert "over-range" in p.lights["Sensor stream"].detail.text()
    p.set_state("tripped", "estop: operator E-stop (GUI)")
    assert p.rearm_button.isEnabled() and "operator E-stop" in p.banner.text()
    p.set_state("armed")
    assert not p.rearm_button.isEnabled()
    p.estop_button.setDisabled(True)
    assert p.estop_button.isEnabled()
    p.set_state("paused", "operator")  # an operator's pause: no banner
    assert p.banner.isHidden()
    p.set_state("paused", rerun_wait_reason(2))
    assert not p.banner.isHidden() and "2 aborted trial(s) can be re-run" in p.banner.text()
    p.set_state("armed", "next trial 3")
    assert p.banner.isHidden()


def test_safety_panel_shows_confirmed_weakened_settings(qtbot):
    from nmsid.rig.gui.safety_panel import SafetyPanel
    p = SafetyPanel(on_estop=lambda: None, on_rearm=lambda: None)
    qtbot.addWidget(p)
    p.show()
    assert not p.weakened.isVisible()
    p.set_weakened(["interlock.trip_on_overrun = false (that interlock rule never trips)"])
    assert p.weakened.isVisible()
    assert p.weakened.text() == ("WEAKENED SAFETY (confirmed in the configuration): "
                                 "interlock.trip_on_overrun = false (that interlock rule "
                                 "never trips)")
    p.set_weakened([])
    assert not p.weakened.isVisible()


def test_schedule_panel_in_the_wait_for_a_rerun(qtbot):
    from nmsid.protocols.schedule import PlannedTrial, TrialStatus
    from nmsid.rig.gui.schedule_panel import SchedulePanel
    p = SchedulePanel(on_pause=lambda: None, on_resume=lambda: None, on_skip=lambda: None,
                      on_rerun=lambda i: None, on_end=lambda: None)
    qtbot.addWidget(p)
    sched = [PlannedTrial(i, 0.5, i + 1) for i in range(3)]
    for pt, st in zip(sched, (TrialStatus.DONE, TrialStatus.ABORTED, TrialStatus.DONE),
                      strict=True):
        pt.status = st
    p.set_schedule(sched)
    p.set_state("paused", "operator")
    assert p.resume_button.isEnabled() and p.skip_button.isEnabled()
    assert not p.waiting_for_rerun
    p.set_state("paused", rerun_wait_reason(1))
    assert p.waiting_for_rerun
    assert not p.resume_button.isEnabled() and not p.skip_button.isEnabled()
    assert not p.pause_button.isEnabled()
    assert p.rerun_button.isEnabled() and p.end_button.isEnabled()


# -- calibration panel ---------------------------------------------------------------------
def test_calibration_panel_marks_detected_and_refuses_inverted_currents(qtbot):
    from nmsid.rig.gui.calibration_panel import CalibrationPanel
    confirmed = []
    p = CalibrationPanel(on_confirm=confirmed.append)
    qtbot.addWidget(p)
    for k in range(5):
        p.add_step("extensor", 1.0 + k, 1.2 * k)
        p.add_step("flexor", 1.0 + k, 1.1 * k)
    assert len(p.points["ext"]) == 5 and len(p.points["flex"]) == 5
    ramps = {"ext_I_mA": np.arange(5.0)}
    p.set_result(Calibration(1.5, 5.0, 1.5, 5.5, ramps=ramps))
    assert p.confirm_button.isEnabled()
    assert p.lines["Iemax_mA"].value() == 5.0 and p.lines["Iemax_mA"].isVisible()
    p.set_values(Iemax_mA=1.0)  # below Iemin: refused, nothing sent
    p.confirm()
    assert not confirmed and "Iemax_mA > Iemin_mA" in p.status.text()
    p.set_values(Iemax_mA=6.0)
    p.confirm()
    assert confirmed[0].Iemax_mA == 6.0 and confirmed[0].Iemin_mA == 1.5
    assert "ext_I_mA" in confirmed[0].ramps  # measured ramps kept with the edit
    assert not p.confirm_button.isEnabled()
    with pytest.raises(ValueError, match="unknown calibration field"):
        p.set_values(Imax=3)


# -- identification panel ------------------------------------------------------------------
def test_identification_runs_in_a_worker_and_flags_poor_fits(qtbot):
    import threading

    from nmsid.rig.gui.identification_panel import IdentificationPanel
    threads = []

    class R:
        def __init__(self, sE, fit):
            self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = sE * 2, 12.0, 0.6, fit

    def identify(trials):
        threads.append(threading.current_thread().name)
        sE = trials[0]
        if sE > 0.9:
            raise ValueError("no usable trial")
        return R(sE, 95.0 if sE < 0.7 else 40.0)

    p = IdentificationPanel(identify=identify)
    qtbot.addWidget(p)
    for sE in (0.5, 0.8, 0.95):
        p.submit_level(sE, [sE])
    qtbot.waitUntil(lambda: p.pending == 0, timeout=5000)
    assert [pt.sE for pt in p.points] == [0.5, 0.8]
    assert threads and all(t.startswith("nmsid-identify") for t in threads)
    assert len(p.errors) == 1 and "sE = 0.95" in p.errors[0]
    x, y = p.bad_scatter["fit_pct"].getData()
    assert list(x) == [0.8] and list(y) == [40.0]
    p.shutdown()


# -- results panel -------------------------------------------------------------------------
def test_model_curves_match_the_twin_file_definitions():
    from nmsid.rig.gui.results_panel import model_curve
    sE = np.array([0.3, 0.7])
    np.testing.assert_allclose(model_curve("linear", [1, 2], sE), 1 + 2 * sE)
    np.testing.assert_allclose(model_curve("quadratic", [1, 2, 3], sE), 1 + 2 * sE + 3 * sE**2)
    np.testing.assert_allclose(model_curve("exponential", [0.5, 2], sE), 0.5 * np.exp(2 * sE))
    with pytest.raises(ValueError, match="unknown parameter model"):
        model_curve("cubic", [1], sE)


def test_results_panel_shows_tables_and_saves_beside_the_session(qtbot, tmp_path):
    from nmsid.rig.gui.results_panel import (
        ModelFit,
        ParameterSelection,
        ResultsPanel,
        SelectionView,
    )
    sE = np.linspace(0.3, 1.0, 8)
    view = SelectionView([ParameterSelection(
        "Kp", "N", sE, 1 + 2 * sE,
        [ModelFit("linear", -10.0, (1.0, 2.0)), ModelFit("quadratic", -8.0, (1.0, 2.0, 0.0)),
         ModelFit("exponential", 3.0, (1.2, 1.0))], "linear", "Figure 4")])
    p = ResultsPanel(select_models=lambda path: view)
    qtbot.addWidget(p)
    p.run(tmp_path / "S01.h5")
    qtbot.waitUntil(lambda: not p.busy, timeout=5000)
    assert p.table.item(0, 1).text() == "-10.00" and p.table.item(0, 4).text() == "linear"
    assert p.table.item(0, 1).font().bold()
    names = sorted(x.name for x in p.saved)
    assert names == ["gui_model_selection.csv", "gui_model_selection.png"]
    rows = (tmp_path / "S01-analysis" / "gui_model_selection.csv").read_text().splitlines()
    assert rows[0].startswith("parameter,units,model,AICc,selected")
    assert len(rows) == 4
    p.shutdown()
