"""A complete simulated session driven through the GUI: the real engine, the real-time
simulated rig, a shortened schedule (2 sE x 2 repeats, 0.5 s lead-in + 1.6 s chirp).

start -> calibrate (confirm an edited value) -> E-stop mid-trial (trial aborted, output
zero, interlock latched, stimulation stays off) -> re-arm -> re-run -> finish; the file is
valid and complete.
"""

from __future__ import annotations

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.states import State


def test_complete_session_with_estop_rearm_rerun(sim_window, qtbot, tmp_path):
    w = sim_window
    out = tmp_path / "G01.h5"
    w.start_session(participant="G01", output=out, backend="sim", seed=5, realtime=True)
    assert w.controller.engine is not None, w.setup_panel.message.text()
    engine = w.controller.engine
    rig = w.rigs[0]

    # -- calibration: the ramps are drawn, the detected currents offered, one edited
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=30000)
    assert w.state is State.CALIBRATING
    assert len(w.calibration_panel.points["ext"]) >= 2
    assert len(w.calibration_panel.points["flex"]) >= 2
    detected = w.calibration_panel.current_values()
    assert w.calibration_panel.lines["Iemax_mA"].value() == detected["Iemax_mA"]
    assert rig.run_records and not any(r.trial is not None for r in rig.run_records), \
        "no trial may run before the operator confirms the calibration"
    edited_Iemax = detected["Iemax_mA"] + 0.5
    w.confirm_calibration(Iemax_mA=edited_Iemax)

    # -- E-stop in the middle of the second trial
    qtbot.waitUntil(lambda: w.trial_statuses()[1:2] == ["running"], timeout=30000)
    # the stimulator's own status too, not only the plot: on a loaded machine the plot can
    # lag the real-time rig by more than the 1.6 s chirp, and an E-stop after the output
    # ended has no output to zero
    qtbot.waitUntil(lambda: w.buffer.snapshot().n > 0 and w.buffer.snapshot().t_s[-1] > 0.6
                    and w.buffer.snapshot().trial_index == 1
                    and rig.stimulator.status().output_active, timeout=10000)
    qtbot.keyClick(w.tabs, " ")  # Space: the application-wide E-stop key
    qtbot.waitUntil(lambda: w.state is State.TRIPPED, timeout=5000)
    assert w.trial_statuses()[1] == "aborted"
    assert "estop" in engine.schedule[1].reason
    assert not rig.stimulator.status().output_active
    assert rig.output_zero_events, "the stimulator output was set to zero"
    assert engine.interlock.latched
    assert w.safety.lights["Interlock latch"].ok is False
    assert w.safety.banner.isVisible() and "estop" in w.safety.banner.text()
    assert w.safety.rearm_button.isEnabled()
    n_runs = len(rig.run_records)
    qtbot.wait(400)  # latched: nothing starts until the operator re-arms
    assert len(rig.run_records) == n_runs and w.state is State.TRIPPED
    w.add_note("E-stop test: participant fine")

    # -- re-arm clears the latch only; re-run the aborted trial; CONTINUE goes on
    assert not w.safety.continue_button.isEnabled()
    w.safety.rearm_button.click()
    qtbot.waitUntil(lambda: w.state is State.PAUSED, timeout=5000)
    assert not engine.interlock.latched
    assert w.safety.state_label.text() == "RE-ARMED"
    assert "CONTINUE" in w.safety.banner.text() and w.safety.continue_button.isEnabled()
    qtbot.waitUntil(lambda: w.safety.lights["Interlock latch"].ok is True, timeout=5000)
    qtbot.wait(400)  # re-armed, not continued: nothing is stimulated
    assert len(rig.run_records) == n_runs and w.state is State.PAUSED
    qtbot.waitUntil(lambda: w.schedule_panel.rerun_button.isEnabled(), timeout=5000)
    w.schedule_panel.rerun_button.click()
    w.safety.continue_button.click()
    qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                    timeout=60000)
    assert w.run_error is None
    assert w.run_result.complete and w.state is State.FINISHED
    assert w.trial_statuses() == ["done"] * 4
    assert w.schedule_panel.progress.value() == 4

    # -- the file: valid, complete, the abort and the note recorded
    assert validate_session(out) == []
    s = read_session(out)
    assert s.calibration.Iemax_mA == edited_Iemax
    done = {int(t.extra_attrs["schedule_index"]) for t in s.trials if t.completed}
    assert done == {0, 1, 2, 3}
    aborted = [t for t in s.trials if not t.completed]
    assert len(aborted) == 1 and "estop" in aborted[0].abort_reason
    assert 0 < aborted[0].n_samples < s.completed_trials()[0].n_samples
    kinds = [e.kind for e in s.events]
    assert "interlock_trip" in kinds and "rearmed" in kinds
    assert any(e.kind == "note" and "participant fine" in e.detail for e in s.events)
    assert any("participant fine" in line for line in w.event_log.lines)

    # -- running identification: one point per level, computed off the GUI thread
    qtbot.waitUntil(lambda: w.identification.pending == 0, timeout=30000)
    assert sorted(round(p.sE, 2) for p in w.identification.points) == [0.4, 0.7]
    assert all(p.Kp > 0 and p.wn_rad_s > 0 for p in w.identification.points)
    assert w.live.frames_drawn > 10


def test_pause_resume_skip_end_then_resume_the_file(sim_window_manual, qtbot, tmp_path):
    w = sim_window_manual
    out = tmp_path / "G02.h5"
    sp = w.schedule_panel
    w.start_session(participant="G02", output=out, backend="sim", seed=2, realtime=True)
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=30000)
    w.confirm_calibration()  # hand-entered currents: confirmed as they are
    rig = w.rigs[0]

    # Pause during trial 0: policy "finish" lets it complete, then holds with output off
    qtbot.waitUntil(lambda: w.trial_statuses()[:1] == ["running"], timeout=30000)
    qtbot.waitUntil(lambda: sp.pause_button.isEnabled(), timeout=5000)
    sp.pause_button.click()
    qtbot.waitUntil(lambda: w.state is State.PAUSED, timeout=10000)
    assert w.trial_statuses()[0] == "done"
    assert not rig.stimulator.status().output_active
    n_runs = len(rig.run_records)
    qtbot.wait(300)
    assert len(rig.run_records) == n_runs and w.state is State.PAUSED
    assert sp.resume_button.isEnabled() and not sp.pause_button.isEnabled()
    sp.resume_button.click()

    # Skip the running trial 1: aborted "skipped by operator"
    qtbot.waitUntil(lambda: w.trial_statuses()[1:2] == ["running"], timeout=10000)
    sp.skip_button.click()
    qtbot.waitUntil(lambda: w.trial_statuses()[1:2] == ["aborted"], timeout=10000)
    assert "skipped" in w.controller.engine.schedule[1].reason

    # End the session early: two clicks
    qtbot.waitUntil(lambda: sp.end_button.isEnabled(), timeout=5000)
    sp.end_button.click()
    assert w.run_result is None and sp.end_button.text() != "End session"
    sp.end_button.click()
    qtbot.waitUntil(lambda: w.run_result is not None, timeout=10000)
    assert not w.run_result.complete
    n_before = sum(t.completed for t in read_session(out).trials)

    # the set-up panel is ready again; the unfinished file is refused for a new session
    # (never overwritten) and offered for resume
    assert w.setup_panel.isEnabled()
    w.setup_panel.set_values(participant="G02", output=out)
    assert not w.setup_panel.start_button.isEnabled()
    assert not w.setup_panel.resume_button.isHidden()
    w.setup_panel.resume_button.click()
    assert w.controller.engine is not None and w.controller.engine.resume_mode
    qtbot.waitUntil(lambda: w.run_result is not None, timeout=60000)
    assert w.run_error is None and w.run_result.complete
    assert not w.calibration_panel.confirm_button.isEnabled()  # known from the file
    assert validate_session(out) == []
    s = read_session(out)
    assert sum(t.completed for t in s.trials) == 4 > n_before
    assert {int(t.extra_attrs["schedule_index"]) for t in s.trials if t.completed} == \
        {0, 1, 2, 3}
    assert any("skipped" in t.abort_reason for t in s.trials if not t.completed)


def test_fault_trip_then_model_selection_on_the_fast_clock(fast_sim_window, qtbot,
                                                            tmp_path):
    """Six sE levels on the simulator's fast clock. A force spike trips the force-limit
    rule: the GUI shows the rule and the reason, stays tripped until re-armed; the trial
    is re-run. At the end: identification per level, then the model selection (AICc
    table, Figures 4-6) in the window and written beside the file."""
    w = fast_sim_window
    out = tmp_path / "G03.h5"
    w.start_session(participant="G03", output=out, backend="sim", seed=4, realtime=False)
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=30000)
    w.confirm_calibration()
    qtbot.waitUntil(lambda: w.state is State.TRIPPED, timeout=30000)
    assert w.trial_statuses()[1] == "aborted"
    assert "force_limit" in w.controller.engine.schedule[1].reason
    assert "force_limit" in w.safety.banner.text()
    assert w.safety.lights["Force limit"].ok is False
    assert w.safety.lights["Interlock latch"].ok is False
    assert not w.rigs[0].stimulator.status().output_active
    qtbot.wait(200)
    assert w.state is State.TRIPPED  # latched: the fast clock does not run on
    w.rerun(1)  # queue the re-run, then re-arm and continue
    w.rearm()
    qtbot.waitUntil(lambda: w.safety.continue_button.isEnabled(), timeout=30000)
    w.continue_session()
    qtbot.waitUntil(lambda: w.run_result is not None, timeout=60000)
    assert w.run_error is None and w.run_result.complete
    qtbot.waitUntil(lambda: w.identification.pending == 0 and not w.results.busy,
                    timeout=60000)
    assert len(w.identification.points) == 6
    assert w.results.error == "", w.results.error
    assert w.tabs.currentWidget() is w.results
    table = w.results.table
    assert [table.item(r, 0).text().split()[0] for r in range(table.rowCount())] == \
        ["Kp", "wn", "zeta"]
    for r in range(3):
        assert table.item(r, 4).text() in ("linear", "quadratic", "exponential")
    assert set(w.results.plots) == {"Kp", "wn", "zeta"}
    analysis = tmp_path / "G03-analysis"
    for name in ("model_selection.json", "tables.txt", "gui_model_selection.png",
                 "gui_model_selection.csv", "figure_Kp.png"):
        assert (analysis / name).exists(), name
    assert "AICc" in w.results.tables_text.toPlainText()
    assert validate_session(out) == []
    s = read_session(out)
    assert [t.abort_reason.split(":")[0] for t in s.trials if not t.completed] == \
        ["force_limit"]


def test_bad_configuration_is_refused_before_anything_runs(fast_sim_window, tmp_path):
    w = fast_sim_window
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[protocol]\nchirp_f1_Hz = 5000.0\n")
    w.start_session(participant="G04", output=tmp_path / "G04.h5", config=cfg)
    assert w.controller.engine is None and not w.rigs
    assert "protocol.chirp_f1_Hz" in w.setup_panel.message.text()
    assert not (tmp_path / "G04.h5").exists()


def test_engine_error_is_shown_and_output_stays_off(make_sim_window, qtbot, tmp_path):
    """A ceiling above what the (simulated) stimulator can deliver is refused by the
    engine before anything is stimulated; the window shows the error."""
    import dataclasses

    def too_high(cfg):
        return cfg.replace(calibration=dataclasses.replace(cfg.calibration,
                                                           ceiling_ext_mA=40.0))
    w = make_sim_window(too_high)
    w.start_session(participant="G05", output=tmp_path / "G05.h5")
    qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                    timeout=20000)
    assert isinstance(w.run_error, ValueError)
    assert "ceiling_ext_mA" in w.safety.banner.text()
    assert not w.rigs[0].run_records  # nothing was ever started
    assert w.state is State.FINISHED


def test_calibration_above_the_ceiling_is_refused_and_asked_again(make_sim_window, qtbot,
                                                                  tmp_path):
    w = make_sim_window()
    out = tmp_path / "G06.h5"
    w.start_session(participant="G06", output=out, realtime=False)
    panel = w.calibration_panel
    qtbot.waitUntil(lambda: panel.confirm_button.isEnabled(), timeout=30000)
    ceiling = w.controller.config.calibration.ceiling_ext_mA
    w.confirm_calibration(Iemax_mA=ceiling + 5)
    qtbot.waitUntil(lambda: panel.confirm_button.isEnabled(), timeout=10000)
    assert "above the extensor ceiling" in panel.status.text()
    assert not w.rigs[0].run_records or all(r.trial is None for r in w.rigs[0].run_records)
    w.confirm_calibration(Iemax_mA=ceiling - 1)
    qtbot.waitUntil(lambda: w.run_result is not None, timeout=60000)
    assert w.run_result.complete
    assert read_session(out).calibration.Iemax_mA == ceiling - 1
    cal_cfg = w.controller.config.calibration
    assert max(w.rigs[0].max_sent_mA) <= max(cal_cfg.ceiling_ext_mA, cal_cfg.ceiling_flex_mA)
