"""A GUI in step with the rig (issue 39): notifications in batches, none dropped; the QC
off the GUI thread; E-stop never a silent latch; RE-ARM apart from CONTINUE; readouts;
one force unit; both muscles' thresholds; problems shown; time left on the rig's clock;
trials named as in the file."""

from __future__ import annotations

import threading
import time

import numpy as np

from nmsid.protocols.session_file import Calibration, Event, read_session
from nmsid.rig.states import State


# -- notifications: batched, none dropped, the latest state shown ---------------------------
def test_a_flood_of_notifications_is_shown_in_batches_none_dropped(fake_window, qtbot):
    """The engine thread posts 3000 events and state changes as fast as it can (the fast
    clock): every event reaches the log, in order, the state label shows the last state,
    and the GUI thread took them in batches at most one per DRAIN_INTERVAL_S."""
    from nmsid.rig.gui.main_window import DRAIN_INTERVAL_S
    from nmsid.rig.gui.observer import QtEngineObserver
    w = fake_window
    obs = QtEngineObserver(w.signals, w.buffer, w.controller.mailbox)
    states = [State.ARMED, State.STIMULATING, State.RESTING]
    n = 3000

    def engine():
        for i in range(n):
            obs.on_event(Event("2026-01-01T00:00:00Z", "note", f"n{i}"))
            obs.on_state(states[i % 3], states[(i + 1) % 3], "")
        obs.on_state(State.RESTING, State.PAUSED, "operator")

    t0 = time.perf_counter()
    batches0 = w.n_batches
    th = threading.Thread(target=engine)
    th.start()
    th.join()
    qtbot.waitUntil(lambda: sum(line.startswith("") and " n" in line
                                for line in w.event_log.lines) >= n, timeout=60_000)
    elapsed = time.perf_counter() - t0
    notes = [line.split()[-1] for line in w.event_log.lines if "note" in line]
    assert notes == [f"n{i}" for i in range(n)]  # all of them, in order
    qtbot.waitUntil(lambda: w.safety.state_label.text() == "PAUSED", timeout=5_000)
    assert w.state is State.PAUSED
    # batches, not one GUI call per notification (the timer spaces them; +2: the first
    # comes at once, and rounding)
    assert w.n_batches - batches0 <= elapsed / DRAIN_INTERVAL_S + 2
    assert w.n_batches - batches0 < n / 10


def test_quality_control_runs_off_the_gui_thread_and_coalesces_per_level(qtbot):
    from nmsid.protocols.session_file import Trial
    from nmsid.rig.gui.trial_qc import TrialQC
    release = threading.Event()
    judged: list[tuple[str, tuple]] = []
    got: list[dict] = []

    def judge(trials):
        judged.append((threading.current_thread().name, tuple(sorted(trials))))
        release.wait(10)
        return dict.fromkeys(trials, ("used", ""))

    qc = TrialQC(judge, got.append)
    z = np.zeros(10)

    def trial(sE):
        return Trial(sE=sE, repeat=1, fs_Hz=2000.0, rE=z, I_ext_mA=z, I_flex_mA=z,
                     force_N=z)
    qc.submit(0, trial(0.5))        # starts at once and blocks in judge
    qtbot.waitUntil(lambda: len(judged) == 1)
    qc.submit(1, trial(0.5))        # stale: a newer job of its level follows
    qc.submit(2, trial(0.5))
    release.set()
    qtbot.waitUntil(lambda: qc.pending == 0, timeout=10_000)
    assert all(name.startswith("nmsid-qc") for name, _ in judged)
    assert [ids for _, ids in judged] == [(0,), (0, 1, 2)]  # the middle job was skipped
    assert got[-1] == {0: ("used", ""), 1: ("used", ""), 2: ("used", "")}
    qc.shutdown(wait=True)


# -- a whole fast-clock session: E-stop, RE-ARM / CONTINUE, names, readouts, time left ------
def test_fast_session_estop_anytime_rearm_continue_names_readouts(fast_sim_window, qtbot,
                                                                  tmp_path):
    w = fast_sim_window
    out = tmp_path / "S39.h5"
    w.start_session(participant="S39", output=out, backend="sim", seed=4, realtime=False)
    # both muscles' thresholds are drawn from the start: extensor +F, flexor -F
    cfg = w.controller.config.calibration
    lines = w.calibration_panel.force_lines
    assert (lines["ext_Fmin"].value(), lines["ext_Fmax"].value()) == (cfg.Fmin_N, cfg.Fmax_N)
    assert (lines["flex_Fmin"].value(), lines["flex_Fmax"].value()) == \
        (-cfg.Fmin_N, -cfg.Fmax_N)
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=30_000)
    w.confirm_calibration()
    # the force spike in the second trial trips the force limit
    qtbot.waitUntil(lambda: w.state is State.TRIPPED, timeout=30_000)
    assert w.safety.rearm_button.isEnabled() and not w.safety.continue_button.isEnabled()
    # readouts: the last commanded currents were shown; output off now reads 0 mA
    assert w.live.readouts.numbers["I_ext"] == 0.0 and w.live.readouts.numbers["I_flex"] == 0.0
    assert w.live.readouts.values["force"].text() not in ("", "-")
    # an E-stop while already latched: the interlock writes only its first trip, so the
    # window records the press as a note (never a silent press)
    w.press_estop()
    qtbot.waitUntil(lambda: any("E-STOP pressed" in line for line in w.event_log.lines),
                    timeout=10_000)
    # RE-ARM clears the latch only: the engine holds until CONTINUE
    w.rerun(1)
    w.safety.rearm_button.click()
    qtbot.waitUntil(lambda: w.safety.continue_button.isEnabled(), timeout=10_000)
    engine = w.controller.engine
    assert not engine.interlock.latched and w.state is State.PAUSED
    assert w.safety.state_label.text() == "RE-ARMED"
    n_trials = sum(p.attempts for p in engine.schedule)
    qtbot.wait(300)  # the fast clock would have run several trials by now
    assert sum(p.attempts for p in engine.schedule) == n_trials
    # time left: on the rig's (virtual) clock, said so
    qtbot.waitUntil(lambda: "rig's clock (fast clock" in w.schedule_panel.time_left.text(),
                    timeout=5_000)
    w.safety.continue_button.click()
    qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                    timeout=120_000)
    assert w.run_error is None and w.run_result.complete
    # trials named as in the file: the schedule's column holds each row's file names
    s = read_session(out, load_data=False)
    shown = {i: w.schedule_panel.names.text(i) for i in range(len(engine.schedule))}
    in_file: dict[int, list[str]] = {}
    for t in s.trials:
        in_file.setdefault(int(t.extra_attrs["schedule_index"]), []).append(t.name)
    assert shown == {i: ", ".join(v) for i, v in in_file.items()}
    assert w.schedule_panel.table.item(1, 0).text() == shown[1] and "," in shown[1]
    assert w.live.title.text().startswith(s.trials[-1].name + ":")
    assert any(e.kind == "note" and "E-STOP pressed" in e.detail for e in s.events)
    # the E-stop after the end: refused in the window, nothing latched, file unchanged
    n_events = len(s.events)
    w.press_estop()
    assert w.safety.notice.isVisible() and "session has ended" in w.safety.notice.text()
    assert any("E-STOP: the session has ended" in line for line in w.event_log.lines)
    qtbot.wait(300)  # a light poll or two
    assert w.safety.light_states()["Interlock latch"] is None  # grey: not red
    assert len(read_session(out, load_data=False).events) == n_events


def test_estop_the_engine_took_but_never_wrote_is_named_when_the_run_ends(fake_window, qtbot,
                                                                         tmp_path):
    """The fake engine (as the real one in its last moments) takes an E-stop without
    writing it: when the run ends the window says the file does not record it."""
    w = fake_window
    w.start_session(participant="F01", output=tmp_path / "F01.h5")
    qtbot.waitUntil(lambda: w.calibration_panel.confirm_button.isEnabled(), timeout=10_000)
    w.confirm_calibration()
    qtbot.waitUntil(lambda: w.state is State.STIMULATING, timeout=10_000)
    w.press_estop()
    assert not w.safety.notice.isVisible()  # not yet: the engine may still write it
    w.end_session()
    qtbot.waitUntil(lambda: w.run_result is not None or w.run_error is not None,
                    timeout=30_000)
    assert w.safety.notice.isVisible()
    assert "does not record it" in w.safety.notice.text()


def test_estop_before_any_session_is_refused_visibly(fake_window):
    w = fake_window
    w.press_estop()
    assert w.safety.notice.isVisible() and "no session is running" in w.safety.notice.text()
    assert w.safety.light_states()["Interlock latch"] is None


# -- panels -----------------------------------------------------------------------------------
def test_force_axis_keeps_newtons_for_small_forces(qtbot):
    """pyqtgraph's automatic SI prefix turned the axis to mN when a trial's force stayed
    small; the unit is N for the whole session."""
    from nmsid.rig.gui.live_buffer import LiveBuffer
    from nmsid.rig.gui.live_plots import LivePlots
    buf = LiveBuffer(window_s=1.0, fs_Hz=100.0)
    live = LivePlots(buf)
    qtbot.addWidget(live)
    live.show()
    axis = live.force_plot.getAxis("left")
    for scale_N in (5.0, 0.004, 3.0):
        buf.start_trial(0)
        live.reset_view()
        f = scale_N * np.sin(np.arange(50) / 5)
        buf.append(0, 0, f, np.zeros(50), np.full(50, 7.5), np.zeros(50))
        live.readouts.output_on()
        live.redraw()
        qtbot.wait(20)
        assert axis.autoSIPrefixScale == 1.0 and "(N)" in axis.labelText
        assert live.readouts.values["force"].text() == f"{f[-1]:+.2f}"
        assert live.readouts.values["I_ext"].text() == "7.5"
    assert live.i_plot.getAxis("left").autoSIPrefixScale == 1.0
    live.readouts.output_off()
    assert live.readouts.values["I_ext"].text() == "0.0"


def test_calibration_result_moves_both_muscles_threshold_lines(qtbot):
    from nmsid.rig.gui.calibration_panel import CalibrationPanel
    p = CalibrationPanel(on_confirm=lambda cal: None)
    qtbot.addWidget(p)
    p.set_result(Calibration(2.0, 8.0, 2.5, 9.0, Fmin_N=0.8, Fmax_N=6.0))
    got = {k: line.value() for k, line in p.force_lines.items()}
    assert got == {"ext_Fmin": 0.8, "ext_Fmax": 6.0, "flex_Fmin": -0.8, "flex_Fmax": -6.0}
    assert all(line.isVisible() for line in p.force_lines.values())


def test_results_panel_lists_the_problems_in_the_window(qtbot):
    from nmsid.rig.gui.results_panel import ResultsPanel, SelectionView
    p = ResultsPanel(select_models=None)
    qtbot.addWidget(p)
    problems = ["P01: sE 0.30: fit 41 % below 70 %", "twin not written: no calibration"]
    p._on_done(SelectionView([], problems=problems), None)
    assert p.problems.isVisibleTo(p)
    text = p.problems.toPlainText()
    assert all(line in text for line in problems)
    assert "2 problem(s), listed below" in p.status.text()
    p.reset()
    assert not p.problems.isVisibleTo(p)


def test_time_left_counts_on_the_rigs_clock_and_its_pace(qtbot):
    from nmsid.protocols.schedule import PlannedTrial, TrialStatus
    from nmsid.rig.gui.schedule_panel import SchedulePanel
    p = SchedulePanel(lambda: None, lambda: None, lambda: None, lambda i: None)
    qtbot.addWidget(p)
    p.set_timing(15.0, 60.0)
    sched = [PlannedTrial(i, 0.5, i + 1) for i in range(3)]
    sched[0].status = TrialStatus.RUNNING
    p.set_schedule(sched, 0)
    # real time: the rest of the running trial (10 s), two trials, two rests
    p.set_clock(100.0, 0.0, in_trial_s=5.0, realtime=True)
    assert p.time_left.text() == "time left: ~2 min 40 s"
    # the fast clock: 200 rig seconds per wall second
    p.set_clock(0.0, 10.0, 5.0, realtime=False)
    p.set_clock(200.0, 11.0, 5.0, realtime=False)
    assert p.time_left.text() == ("time left: ~2 min 40 s on the rig's clock (fast clock, "
                                  "200x real time: ~1 s wall)")


def test_notifications_posted_while_a_batch_is_shown_join_that_batch(fake_window):
    """An engine that posts while the window shows a batch (its trial end, the next state)
    has them shown in the same batch, before the one schedule refresh: they do not wait
    for the next refresh and interlock poll (bench/bench_gui_lag.py: 0.7 s on a busy
    machine)."""
    w = fake_window
    shown: list[str] = []
    refreshes: list[int] = []
    box = w.controller.mailbox
    box.take()

    def on_event(event):
        shown.append(event)
        if event == "first":
            box.put("event", ("posted meanwhile",))

    w._handlers["event"] = on_event
    w._refresh_schedule = lambda: refreshes.append(len(shown))  # type: ignore[method-assign]
    box.put("event", ("first",))
    w._drain()
    assert shown == ["first", "posted meanwhile"]
    assert refreshes == [2]  # one refresh, after both
    assert box.pending() == 0


def test_a_plot_frame_shows_the_pending_notifications_first(fake_window):
    """A frame of the live plots (and its paint) never holds a notification back: the
    frame takes the mailbox first."""
    w = fake_window
    box = w.controller.mailbox
    box.take()
    box.put("event", ("before the frame",))
    w.live._next_due = 0.0
    w.live._tick()
    assert box.pending() == 0
    assert w.event_log.lines[-1] == "before the frame"


def test_live_plot_frames_budget_counts_the_paint(qtbot):
    """After a frame whose paint took long, the next frame waits at least DRAW_SHARE_WAIT
    times that (frames are dropped on a starved machine, the notifications are not)."""
    from nmsid.rig.gui.live_buffer import LiveBuffer
    from nmsid.rig.gui.live_plots import DRAW_SHARE_WAIT, LivePlots
    plots = LivePlots(LiveBuffer(window_s=1.0, fs_Hz=100.0))
    qtbot.addWidget(plots)
    plots.timer.stop()
    plots.graphics.last_paint_s = 0.5   # a slow paint, as on a busy machine
    t0 = time.perf_counter()
    plots._next_due = 0.0
    plots._tick()
    plots.timer.stop()
    assert plots._next_due >= t0 + DRAW_SHARE_WAIT * 0.5


def test_live_plots_left_axes_have_a_fixed_width(qtbot):
    """A new trial's force range (wider tick labels) never re-lays out the plots."""
    from nmsid.rig.gui.live_buffer import LiveBuffer
    from nmsid.rig.gui.live_plots import LivePlots
    from nmsid.rig.gui.theme import LEFT_AXIS_PX
    plots = LivePlots(LiveBuffer(window_s=1.0, fs_Hz=100.0))
    qtbot.addWidget(plots)
    plots.timer.stop()
    for p in (plots.force_plot, plots.re_plot, plots.i_plot):
        axis = p.getAxis("left")
        # pyqtgraph's AxisItem.setWidth: a fixed width (min = max), not the tick text's
        assert axis.fixedWidth == LEFT_AXIS_PX
        assert axis.minimumWidth() == axis.maximumWidth() >= LEFT_AXIS_PX
