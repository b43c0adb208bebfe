"""The window's own logic over a stand-in engine that follows the contract."""

from __future__ import annotations

from PySide6.QtCore import Qt

from nmsid.protocols.session_file import SessionWriter, read_session, validate_session
from nmsid.rig.states import State


def test_session_through_window_with_estop_rearm_rerun(fake_window, qtbot, tmp_path):
    w = fake_window
    out = tmp_path / "F01.h5"
    w.start_session(participant="F01", output=out)
    assert w.controller.engine is not None, w.setup_panel.message.text()
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=5000)
    assert w.calibration_panel.current_values()["Iemax_mA"] == 7.5
    w.confirm_calibration(Iemax_mA=8.0)
    qtbot.waitUntil(lambda: w.trial_statuses()[1:2] == ["running"], timeout=10000)
    qtbot.waitUntil(lambda: w.buffer.snapshot().n > 0, timeout=5000)
    w.safety.estop_button.click()
    qtbot.waitUntil(lambda: w.state is State.TRIPPED, timeout=5000)
    assert w.controller.engine.output_mA == 0.0
    assert w.safety.rearm_button.isEnabled()
    assert w.safety.banner.isVisible() and "TRIPPED" in w.safety.banner.text()
    assert w.trial_statuses()[1] == "aborted"
    w.add_note("electrode checked")
    # the aborted trial is the last one: after the re-arm the engine waits (paused) for
    # a re-run or the end of the session; the window says so and offers only those
    w.safety.rearm_button.click()
    sp = w.schedule_panel
    qtbot.waitUntil(lambda: w.state is State.PAUSED, timeout=5000)
    assert sp.waiting_for_rerun
    assert w.safety.banner.isVisible() and "Schedule done" in w.safety.banner.text()
    assert "Re-run aborted" in w.safety.banner.text()
    assert sp.rerun_button.isEnabled() and sp.end_button.isEnabled()
    assert not sp.resume_button.isEnabled() and not sp.skip_button.isEnabled()
    assert not sp.pause_button.isEnabled()
    qtbot.wait(200)
    assert w.run_result is None and w.state is State.PAUSED  # it does not finish alone
    sp.rerun_button.click()
    qtbot.waitUntil(lambda: w.run_result is not None, timeout=20000)
    assert w.run_error is None
    assert w.trial_statuses() == ["done"] * 2
    assert not sp.waiting_for_rerun and not w.safety.banner.isVisible()
    assert validate_session(out) == []
    s = read_session(out)
    assert s.calibration.Iemax_mA == 8.0
    assert [t.status for t in s.trials].count("aborted") == 1
    assert any(e.kind == "note" and e.detail == "electrode checked" for e in s.events)
    qtbot.waitUntil(lambda: len(w.identification.points) == 2, timeout=5000)
    assert [p.sE for p in w.identification.points] == [0.4, 0.6]
    assert w.live.frames_drawn > 0


def test_escape_and_space_estop_even_with_rearm_focused(fake_window, qtbot, tmp_path):
    w = fake_window
    calls = []
    w.controller.estop = lambda reason="": calls.append(reason) or True
    w.activateWindow()
    qtbot.waitUntil(lambda: w.isActiveWindow(), timeout=2000)
    qtbot.keyClick(w.schedule_panel.table, Qt.Key.Key_Escape)
    qtbot.keyClick(w.tabs, Qt.Key.Key_Space)
    assert len(calls) == 2
    # a focused button never takes Space for itself: Confirm is not pressed, E-stop is
    confirmed = []
    w.calibration_panel._on_confirm = confirmed.append
    w.calibration_panel.set_awaiting(True)
    w.tabs.setCurrentIndex(1)
    w.calibration_panel.confirm_button.setFocus()
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.hasFocus(), timeout=2000)
    qtbot.keyClick(w.calibration_panel.confirm_button, Qt.Key.Key_Space)
    assert len(calls) == 3 and not confirmed
    for b in (w.safety.rearm_button, w.schedule_panel.rerun_button,
              w.schedule_panel.end_button):
        assert b.focusPolicy() == Qt.FocusPolicy.NoFocus
    # typing a note: Space types a space, Escape still stops
    w.event_log.note.setFocus()
    qtbot.keyClicks(w.event_log.note, "a b")
    assert w.event_log.note.text() == "a b" and len(calls) == 3
    qtbot.keyClick(w.event_log.note, Qt.Key.Key_Escape)
    assert len(calls) == 4
    # the E-STOP button is never disabled
    w.safety.estop_button.setEnabled(False)
    w.setEnabled(True)
    assert w.safety.estop_button.isEnabled()


def test_refuses_existing_finished_file_and_offers_resume(fake_window, tmp_path):
    w = fake_window
    out = tmp_path / "R01.h5"
    SessionWriter.create(out, "R01")
    w.setup_panel.set_values(participant="R01", output=out)
    assert not w.setup_panel.start_button.isEnabled()
    assert w.setup_panel.resume_button.isVisible() or "unfinished" in \
        w.setup_panel.message.text()
    w.start_session()
    assert w.controller.engine is None
    bad = tmp_path / "junk.h5"
    bad.write_text("not hdf5")
    w.setup_panel.set_values(output=bad)
    assert "not a readable session" in w.setup_panel.message.text()
    assert not w.setup_panel.resume_button.isVisible()


def test_script_runner_drives_a_session_and_saves_a_screenshot(fake_window, qtbot, tmp_path):
    from nmsid.rig.gui.script import ScriptRunner, parse_script
    out, shot = tmp_path / "S01.h5", tmp_path / "shots" / "end.png"
    # forward slashes: the script is split like a POSIX shell line, where an unquoted
    # backslash (a Windows path's) escapes the next character
    steps = parse_script(f"""
        start participant=S01 output={out.as_posix()}
        confirm-calibration Iemin_mA=2.5
        wait-trial 1 running 20
        wait-trial-time 0.3 20
        estop
        wait tripped 10
        note "scripted note"
        rerun
        rearm
        wait-finished 30
        tab results
        screenshot {(tmp_path / 'mid.png').as_posix()}
    """, "test-script")
    runner = ScriptRunner(fake_window, steps, screenshot=shot)
    with qtbot.waitSignal(runner.finished, timeout=60000) as sig:
        runner.start()
    ok, message = sig.args
    assert ok, message
    assert shot.exists() and (tmp_path / "mid.png").exists()
    assert validate_session(out) == []
    s = read_session(out)
    assert s.calibration.Iemin_mA == 2.5
    assert any(e.kind == "note" and e.detail == "scripted note" for e in s.events)
    assert fake_window.tabs.currentWidget() is fake_window.results


def test_script_failure_names_the_line(fake_window, qtbot):
    from nmsid.rig.gui.script import ScriptRunner, parse_script
    runner = ScriptRunner(fake_window, parse_script("rearm\n", "s"))
    with qtbot.waitSignal(runner.finished, timeout=5000) as sig:
        runner.start()
    ok, message = sig.args
    assert not ok and "no session is running" in message


def test_estop_stops_the_stimulator_even_if_the_engine_call_fails(fake_window):
    from nmsid.rig.gui.session_controller import SessionController

    stopped = []

    class Broken:
        def estop(self, reason):
            raise RuntimeError("engine broken")

    class Devices:
        class stimulator:  # noqa: N801
            @staticmethod
            def stop_now():
                stopped.append(True)

    c = fake_window.controller
    assert isinstance(c, SessionController)
    c.engine, c.devices = Broken(), Devices()
    try:
        fake_window.press_estop()
    finally:
        c.engine = c.devices = None
    assert stopped == [True]
