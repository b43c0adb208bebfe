"""The operator's window: one place to run a whole session.

Layout: the safety strip (E-STOP, interlock lights, state, trip banner, RE-ARM) across the
top, always visible; under it, tabs (Setup, Calibration, Live trial, Identification,
Results) on the left and the schedule and the event log on the right.

Threads: the engine runs in the controller's worker thread; its notifications arrive as
queued signals (slots below run in the GUI thread); chunks go to the live buffer that the
plot timer reads. Identification and model selection run in worker pools. The methods
``start_session``, ``confirm_calibration``, ``press_estop``, ``rearm``, ``pause``,
``resume``, ``skip``, ``rerun``, ``end_session``, ``add_note`` and ``save_screenshot`` are the
Python API a script or a test uses to drive the window as an operator would.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import Qt, QTimer
from PySide6.QtWidgets import QLabel, QMainWindow, QSplitter, QTabWidget, QVBoxLayout, QWidget

import nmsid.rig.gui.qt_compat  # noqa: F401  (before any signal is emitted)
from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS, joint_named
from nmsid.protocols.session_file import read_session, utc_now
from nmsid.rig.errors import RequestError
from nmsid.rig.gui import analysis_hooks
from nmsid.rig.gui.calibration_panel import CalibrationPanel
from nmsid.rig.gui.event_log import EventLog
from nmsid.rig.gui.identification_panel import IdentificationPanel
from nmsid.rig.gui.live_buffer import LiveBuffer
from nmsid.rig.gui.live_plots import LivePlots
from nmsid.rig.gui.memory import release_freed_memory
from nmsid.rig.gui.observer import EngineSignals
from nmsid.rig.gui.results_panel import ResultsPanel
from nmsid.rig.gui.safety_panel import SafetyPanel, install_estop_shortcuts
from nmsid.rig.gui.schedule_panel import SchedulePanel, planned_fields, status_name
from nmsid.rig.gui.session_controller import DevicesFactory, SessionController, load_session_config
from nmsid.rig.gui.setup_panel import SessionRequest, SetupPanel
from nmsid.rig.gui.trial_qc import TrialQC
from nmsid.rig.observer import is_rerun_wait
from nmsid.rig.states import State

log = logging.getLogger(__name__)

INTERLOCK_POLL_MS = 200
LIVE_WINDOW_S = 10.0
#: The window takes the engine's notifications at most this often (s): one batch, one
#: schedule refresh, however fast the engine runs.
DRAIN_INTERVAL_S = 0.05
#: A batch takes in what the engine posts while it is shown, for at most this long (s);
#: then the schedule is refreshed once. An engine that writes a trial holds Python's GIL
#: in h5py for tenths of a second on a busy machine: notifications posted meanwhile were
#: shown only after the next schedule refresh and interlock poll (~0.7 s later).
DRAIN_BUDGET_S = 0.25
#: Python's GIL switch interval in the GUI process, s (default 0.005). The GUI thread
#: enters Python many times a frame (each slot, each pyqtgraph paint); with the engine,
#: the QC and the identification threads busy, each entry waited up to the interval for
#: the GIL: on a loaded machine the display fell ~2 s behind the fast clock, with 0.5 ms
#: ~0.7 s (bench/bench_gui_lag.py).
GUI_SWITCH_INTERVAL_S = 0.0005
#: The reason the window gives the engine's E-stop (and how it finds it in the events).
ESTOP_REASON = "operator E-stop (GUI)"


def trials_in_file(path) -> list[tuple[int, str]]:
    """(schedule index, name) of each trial already in a session file (resume); empty if
    it cannot be read (a damaged file: the engine recovers it, the names follow)."""
    try:
        trials = read_session(path, load_data=False).trials
    except (ValueError, OSError):
        return []
    return [(int((t.extra_attrs or {}).get("schedule_index", -1)), t.name) for t in trials]


class Tab:
    SETUP, CALIBRATION, LIVE, RESULTS = range(4)


class MainWindow(QMainWindow):
    """The operator GUI.

    Parameters
    ----------
    devices_factory : callable, optional
        ``(request, config) -> RigDevices``; default: simulator or hardware per request.
    engine_factory : callable, optional
        Replaces ``rig.engine.Engine`` (tests).
    config_transform : callable, optional
        ``config -> config`` applied after loading (tests shorten the protocol).
    identify : callable, optional
        ``identify(trials) -> result`` for the running identification; default
        :func:`nmsid.rig.gui.analysis_hooks.identify_level`.
    select_models : callable, optional
        ``select_models(session_path) -> ModelSelection``; default
        :func:`nmsid.rig.gui.analysis_hooks.select_models`.
    auto_tabs : bool
        Switch to the tab that matters when the state changes (calibration, live trial,
        results).
    live_window_s : float
        Length of the rolling force window, s.
    """

    def __init__(self, devices_factory: DevicesFactory | None = None,
                 engine_factory: Callable | None = None,
                 config_transform: Callable | None = None,
                 identify: Callable | None = None, select_models: Callable | None = None,
                 auto_tabs: bool = True, live_window_s: float = LIVE_WINDOW_S):
        super().__init__()
        if sys.getswitchinterval() > GUI_SWITCH_INTERVAL_S:
            sys.setswitchinterval(GUI_SWITCH_INTERVAL_S)
        self.setWindowTitle("nmsid - FES identification session")
        self.auto_tabs = auto_tabs
        self.config_transform = config_transform
        self.state = State.IDLE
        self.trip_reason = ""
        self.current_index = -1
        self.run_result = None
        self.run_error: BaseException | None = None
        self.session_finished = False
        self.joint = JOINTS[DEFAULT_JOINT]
        """The running session's joint (its labels and unit)."""
        self._calibration_known = False
        self._estop_unrecorded = ""
        """UTC time of an E-stop a running engine took and has not yet written to the
        file (cleared by its event; shown as not recorded if the run ends first)."""
        self._rearm_hold = False
        """RE-ARM pressed: the engine holds in ``paused`` until Continue."""
        self._last_drain = 0.0
        self.n_batches = 0
        """Batches of engine notifications shown (each: one schedule refresh)."""

        self.buffer = LiveBuffer(window_s=live_window_s)
        self.signals = EngineSignals()
        self.controller = SessionController(self.signals, self.buffer,
                                            devices_factory=devices_factory,
                                            engine_factory=engine_factory)

        self.safety = SafetyPanel(on_estop=self.press_estop, on_rearm=self.rearm,
                                  on_continue=self.continue_session)
        self.setup_panel = SetupPanel(on_start=self._start_request)
        self.calibration_panel = CalibrationPanel(on_confirm=self._confirm_calibration)
        self.live = LivePlots(self.buffer, before_frame=self._drain_before_frame)
        self.safety.add_readouts(self.live.readouts)
        self.identification = IdentificationPanel(
            identify=identify if identify is not None else analysis_hooks.identify_level)
        self.results = ResultsPanel(
            select_models=select_models if select_models is not None
            else analysis_hooks.select_models)
        self.schedule_panel = SchedulePanel(on_pause=self.pause, on_resume=self.resume,
                                            on_skip=self.skip, on_rerun=self.rerun,
                                            on_end=self.end_session,
                                            on_repeat=self.repeat_excluded)
        self.qc = TrialQC(analysis_hooks.trial_verdicts, self._on_verdicts,
                          executor=self.identification.executor)
        self.event_log = EventLog(on_note=self.add_note)

        self.tabs = QTabWidget()
        self.tabs.addTab(self.setup_panel, "1 Setup")
        self.tabs.addTab(self.calibration_panel, "2 Calibration")
        # the running identification sits under the live plots: the operator sees the
        # parameter curves grow (and a bad fit) without leaving the trial view
        live_split = QSplitter(Qt.Orientation.Vertical)
        live_split.addWidget(self.live)
        live_split.addWidget(self.identification)
        live_split.setStretchFactor(0, 3)
        live_split.setStretchFactor(1, 1)
        live_split.setSizes([600, 250])
        self.tabs.addTab(live_split, "3 Live trial + identification")
        self.tabs.addTab(self.results, "4 Results")
        self.tabs.setFocusPolicy(Qt.FocusPolicy.NoFocus)

        right = QSplitter(Qt.Orientation.Vertical)
        sched_box = QWidget()
        sl = QVBoxLayout(sched_box)
        sl.setContentsMargins(0, 0, 0, 0)
        sl.addWidget(QLabel("<b>Schedule</b>"))
        sl.addWidget(self.schedule_panel)
        log_box = QWidget()
        ll = QVBoxLayout(log_box)
        ll.setContentsMargins(0, 0, 0, 0)
        ll.addWidget(QLabel("<b>Event log</b>"))
        ll.addWidget(self.event_log)
        right.addWidget(sched_box)
        right.addWidget(log_box)
        right.setSizes([520, 300])
        body = QSplitter(Qt.Orientation.Horizontal)
        body.addWidget(self.tabs)
        body.addWidget(right)
        body.setStretchFactor(0, 3)
        body.setStretchFactor(1, 2)
        body.setSizes([960, 560])
        central = QWidget()
        lay = QVBoxLayout(central)
        lay.addWidget(self.safety)
        lay.addWidget(body, 1)
        self.setCentralWidget(central)
        self.resize(1560, 980)
        self.shortcuts = install_estop_shortcuts(self, self.press_estop)

        q = Qt.ConnectionType.QueuedConnection
        self._handlers: dict[str, Callable[..., None]] = {
            "state": self._on_state, "event": self._on_event,
            "calibration_step": self._on_calibration_step,
            "calibration_result": self._on_calibration_result,
            "trial_started": self._on_trial_started, "trial_finished": self._on_trial_finished,
            "level_completed": self._on_level_completed, "finished": self._on_finished}
        self._drain_timer = QTimer(self)
        self._drain_timer.setSingleShot(True)
        self._drain_timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._drain_timer.timeout.connect(self._drain)
        self.signals.notified.connect(self._schedule_drain, q)
        self.signals.run_ended.connect(self._on_run_ended, q)

        self.interlock_timer = QTimer(self)
        self.interlock_timer.setInterval(INTERLOCK_POLL_MS)
        self.interlock_timer.timeout.connect(self._poll_engine)
        self.interlock_timer.start()

    # -- operator API -------------------------------------------------------------------
    def start_session(self, resume: bool = False, **values) -> None:
        """Fill the setup form (participant, backend, config, hw_config, output, seed,
        realtime) and press Start (or Resume)."""
        self.setup_panel.set_values(**values)
        self.setup_panel.press_start(resume=resume)

    def _start_request(self, request: SessionRequest) -> None:
        config = load_session_config(request)
        if self.config_transform is not None and not request.resume:
            config = self.config_transform(config)
        self._reset_for_session()
        in_file = trials_in_file(request.output_path) if request.resume else []
        self.controller.start(request, config=config)
        engine = self.controller.engine
        if request.resume:  # the engine may have recovered one more trial into the file
            self.schedule_panel.reset_session(in_file)
            names = self.schedule_panel.names
            names.count = max(names.count, sum(getattr(p, "attempts", 0) or 0
                                               for p in self.controller.schedule()))
        self._calibration_known = bool(request.resume and
                                       getattr(engine, "calibration", None) is not None)
        used = getattr(engine, "config", config)
        self.joint = joint_named(getattr(used, "joint", DEFAULT_JOINT))
        for panel in (self.live, self.calibration_panel, self.identification):
            panel.set_joint(self.joint)
        self.safety.set_weakened(used.weakened_safety())
        p = used.protocol
        self.schedule_panel.set_timing(p.trial_s, p.rest_s)
        self.calibration_panel.set_thresholds(used.calibration.Fmin_N, used.calibration.Fmax_N)
        self.setup_panel.setEnabled(False)
        self.event_log.append(f"session {request.participant}: "
                              f"{'resuming' if request.resume else 'writing'} "
                              f"{request.output_path} ({request.backend.value})")
        self.setWindowTitle(f"nmsid - {request.participant} - {request.output_path}")
        self._refresh_schedule()
        self._switch(Tab.CALIBRATION)

    def _reset_for_session(self) -> None:
        self.state = State.IDLE
        self.trip_reason = ""
        self.current_index = -1
        self.run_result = self.run_error = None
        self.session_finished = False
        self._estop_unrecorded = ""
        self._rearm_hold = False
        self.controller.mailbox.take()  # nothing of an earlier session is shown
        self.qc.reset()
        self.schedule_panel.reset_session()
        self.safety.clear_notice()
        self.safety.set_trial("")
        self.live.readouts.reset()
        self.calibration_panel.reset()
        self.identification.reset()
        self.results.reset()
        self.buffer.start_trial(-1)
        self.live.reset_view()
        release_freed_memory()  # the last session's freed heap back to the system

    def confirm_calibration(self, **currents_mA: float) -> None:
        """Optionally edit the currents (Iemin_mA=..., ...), then press Confirm."""
        if currents_mA:
            self.calibration_panel.set_values(**currents_mA)
        self.calibration_panel.confirm()

    def _confirm_calibration(self, calibration) -> None:
        self.controller.confirm_calibration(calibration)

    def press_estop(self) -> None:
        """The E-STOP button, Space or Escape: stop output now and latch the interlock.

        Never silent: a running engine writes it to the session file (an
        ``interlock_trip`` event; if the interlock was latched already, a ``note``); with no
        session running (before the start, after the end) nothing can record it and
        nothing latches, and the window says so. An E-stop the engine took as the session
        was ending, and never wrote, is named in the window when the run ends."""
        latched = not self.controller.interlock_status().get("latch", (True, ""))[0] \
            if self.controller.running else False
        if self.controller.estop(ESTOP_REASON):
            self._estop_unrecorded = utc_now()
            if latched:  # the interlock writes only the first trip: record this press
                try:
                    self.controller.add_note(f"E-STOP pressed ({ESTOP_REASON}) while the "
                                             "interlock was latched")
                except RuntimeError:
                    pass
            return
        ended = self.run_result is not None or self.run_error is not None
        text = ("E-STOP: the session has ended, its file is closed: this press is not "
                "recorded and nothing latches. Output is off." if ended else
                "E-STOP: no session is running: nothing to record, nothing latches. "
                "Output is off.")
        self.event_log.append(text)
        self.safety.show_notice(text)

    def rearm(self) -> None:
        """RE-ARM: clear the latch only; the engine then holds (PAUSED, output off)
        until :meth:`continue_session`."""
        self._rearm_hold = True
        self.controller.rearm()

    def continue_session(self) -> None:
        """CONTINUE after a re-arm (or a pause): the next trial starts."""
        self._rearm_hold = False
        self.controller.continue_session()

    def pause(self) -> None:
        self.controller.pause()

    def resume(self) -> None:
        self._rearm_hold = False
        self.controller.resume()

    def skip(self) -> None:
        self.controller.skip_trial()

    def rerun(self, schedule_index: int | None = None) -> None:
        """Re-run an aborted trial (the first aborted one if no index is given)."""
        if schedule_index is None:
            aborted = self.schedule_panel.aborted_indices()
            if not aborted:
                raise ValueError("no aborted trial to re-run")
            schedule_index = aborted[0]
        self.controller.rerun(schedule_index)

    def repeat_excluded(self, schedule_index: int | None = None) -> None:
        """Run a trial the quality control excluded once more (the first such trial if no
        index is given); the recorded one stays in the file."""
        if schedule_index is None:
            excluded = self.schedule_panel.excluded_indices()
            if not excluded:
                raise ValueError("no trial excluded by the quality control to repeat")
            schedule_index = excluded[0]
        _, reasons = self.schedule_panel.qc.get(schedule_index, ("", ""))
        self.controller.repeat_trial(schedule_index, f"QC excluded it: {reasons}")

    def end_session(self) -> None:
        """End the session early: the engine stops output and finishes; the file keeps
        everything recorded and can be resumed later."""
        self.controller.abort()

    def add_note(self, text: str) -> None:
        if self.controller.engine is None:
            self.event_log.append(f"note (not saved: no session running): {text}")
            return
        self.controller.add_note(text)

    def save_screenshot(self, path: str | Path) -> Path:
        """Save a PNG of the whole window (``QWidget.grab``)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not self.grab().save(str(path), "PNG"):
            raise RequestError(f"{path}: could not save the screenshot (is the folder writable?)")
        return path

    # -- engine notifications (GUI thread) -------------------------------------------
    def _schedule_drain(self) -> None:
        """The mailbox has news: take it now, or when ``DRAIN_INTERVAL_S`` has passed
        since the last batch (a flood of notifications costs one batch per interval)."""
        if self._drain_timer.isActive():
            return
        wait_s = self._last_drain + DRAIN_INTERVAL_S - time.perf_counter()
        self._drain_timer.start(max(0, int(wait_s * 1000)))

    def _drain_before_frame(self) -> None:
        """A plot frame is due: what the engine posted is shown first (a frame and its
        paint never hold a notification back)."""
        if self.controller.mailbox.pending():
            self._drain_timer.stop()
            self._drain()

    def _drain(self) -> None:
        """Show every notification the engine posted so far, in order; the schedule, the
        lights and the time left once per batch."""
        self._last_drain = time.perf_counter()
        t_end = self._last_drain + DRAIN_BUDGET_S
        shown = 0
        while True:  # what arrives while a batch is shown is shown too (within the budget)
            items = self.controller.mailbox.take()
            for name, args in items:
                try:
                    self._handlers[name](*args)
                except Exception:  # a display problem must never stop the GUI
                    log.exception("showing the engine's %s notification", name)
            shown += len(items)
            if not items or time.perf_counter() >= t_end:
                break
        if shown:
            self.n_batches += 1
            self._refresh_schedule()
            self._poll_engine()

    def _on_state(self, old, new, reason: str) -> None:
        self.state = new
        name = getattr(new, "value", str(new))
        if new is State.TRIPPED:
            self.trip_reason = reason
        if new in (State.TRIPPED, State.STIMULATING, State.RESTING, State.FINISHED):
            self._rearm_hold = False  # (re-armed -> armed -> paused keeps it)
        self.safety.set_state(name, reason, held=self._rearm_hold and
                              new is State.PAUSED and not is_rerun_wait(new, reason))
        self.schedule_panel.set_state(name, reason)
        if new is State.STIMULATING:
            self.live.readouts.output_on()
        elif new is not State.CALIBRATING:
            self.live.readouts.output_off()
        if new is State.CALIBRATING:
            self._switch(Tab.CALIBRATION)
        elif new is State.STIMULATING:
            self._switch(Tab.LIVE)

    def _on_event(self, event) -> None:
        self.event_log.append(event)
        kind, detail = getattr(event, "kind", ""), str(getattr(event, "detail", ""))
        if (kind == "interlock_trip" or kind == "note") and ESTOP_REASON in detail:
            self._estop_unrecorded = ""
        if getattr(event, "kind", "") == "calibration_refused":
            # the engine still waits: let the operator correct the values
            self.calibration_panel.refused(str(getattr(event, "detail", "")))
            self._switch(Tab.CALIBRATION)

    def _on_calibration_result(self, calibration) -> None:
        if self._calibration_known:
            self.calibration_panel.set_known(calibration)
            return
        self.calibration_panel.set_result(calibration)
        confirm = getattr(getattr(self.controller.config, "calibration", None), "confirm",
                          True)
        self.calibration_panel.set_awaiting(bool(confirm))
        self._switch(Tab.CALIBRATION)

    def _on_calibration_step(self, muscle: str, current_mA: float, force_N: float) -> None:
        self.calibration_panel.add_step(muscle, current_mA, force_N)
        self.live.readouts.calibration_step(muscle, current_mA, force_N)

    def _on_trial_started(self, index: int, planned) -> None:
        self.current_index = index
        sE, repeat, _, _ = planned_fields(planned)
        name = self.schedule_panel.names.started(index)
        self.safety.set_trial(name)
        cfg = getattr(self.controller.engine, "config", None) or self.controller.config
        self.live.set_title(f"{name}: sE = {sE:.2f}, repeat {repeat}",
                            duration_s=cfg.protocol.trial_s if cfg is not None else None)

    def _on_trial_finished(self, index: int, trial) -> None:
        status = getattr(trial, "status", "")
        reason = getattr(trial, "abort_reason", "")
        sE, repeat = getattr(trial, "sE", float("nan")), getattr(trial, "repeat", 0)
        name = self.schedule_panel.names.finished(index, str(getattr(trial, "name", "")))
        self.safety.set_trial(name)
        if status == "completed":  # judged in a worker: the verdict follows (_on_verdicts)
            self.qc.submit(index, trial)
        self.live.set_title(f"{name}: sE = {sE:.2f}, repeat {repeat}: {status}"
                            + (f" ({reason})" if reason else ""))

    def _on_verdicts(self, verdicts: dict) -> None:
        """The quality control's verdicts on one level's completed trials (the earlier
        trials' verdicts may change: a third repeat can decide what two could not)."""
        for i, (decision, why) in verdicts.items():
            before = self.schedule_panel.qc.get(i, ("", ""))[0]
            self.schedule_panel.set_qc(i, decision, why)
            if decision == "excluded" and before != "excluded":
                planned = self.controller.schedule()
                sE, repeat = ((planned[i].sE, planned[i].repeat) if i < len(planned)
                              else (float("nan"), 0))
                self.event_log.append(
                    f"QC: {self.schedule_panel.names.latest(i)} (sE {sE:.2f}, repeat "
                    f"{repeat}) excluded: {why}. 'Repeat excluded' runs it again.")
        self._refresh_schedule()

    def _on_level_completed(self, sE: float, trials: list) -> None:
        self.identification.submit_level(sE, trials)

    def _on_finished(self, path: str) -> None:
        self.session_finished = True
        self._refresh_schedule()

    def _on_run_ended(self, summary, error) -> None:
        self._drain()  # everything the engine posted before it ended, first
        self.run_result, self.run_error = summary, error
        self._refresh_schedule()
        self.safety.set_interlock({})  # no session: the lights are not known
        self.live.readouts.output_off()
        self.setup_panel.new_session()
        if self._estop_unrecorded:
            text = (f"E-STOP at {self._estop_unrecorded[11:19]} UTC came as the session was "
                    "ending: output is off, but the session file does not record it.")
            self.event_log.append(text)
            self.safety.show_notice(text)
            self._estop_unrecorded = ""
        if error is not None:
            self.event_log.append(f"ENGINE STOPPED WITH AN ERROR: {error}")
            self.safety.banner.setText(f"Engine error: {error}. Output is off.")
            self.safety.banner.setStyleSheet("background: #d00000; color: white; "
                                             "font-weight: bold; padding: 6px;")
            self.safety.banner.setVisible(True)
            return
        ended_by = getattr(summary, "ended_by", "")
        n_done = getattr(summary, "n_completed", 0)
        self.event_log.append(f"session ended: {ended_by} ({n_done} trials completed, "
                              f"{getattr(summary, 'n_aborted', 0)} aborted, "
                              f"{getattr(summary, 'n_pending', 0)} not run)")
        if n_done and self.controller.session_path is not None:
            self.results.run(self.controller.session_path)
            self._switch(Tab.RESULTS)

    def _poll_engine(self) -> None:
        """Lights and time left from the engine as it is now (not as notified)."""
        if self.controller.engine is None or not self.controller.running:
            return
        try:
            self.safety.set_interlock(self.controller.interlock_status())
            clock = getattr(self.controller.devices, "clock", None)
            rig_s = float(clock.monotonic_s()) if clock is not None else None
            in_trial_s = (self.buffer.samples_in_trial / self.buffer.fs_Hz
                          if self.buffer.trial_index == self.current_index else 0.0)
            self.schedule_panel.set_clock(rig_s, time.perf_counter(), in_trial_s,
                                          realtime=bool(getattr(clock, "realtime", True)))
        except Exception:  # a display problem must never stop the GUI
            log.exception("reading the interlock status")

    def _refresh_schedule(self) -> None:
        sched = self.controller.schedule()
        if sched:
            self.schedule_panel.set_schedule(sched, self.current_index)

    def _switch(self, tab: int) -> None:
        if self.auto_tabs:
            self.tabs.setCurrentIndex(tab)

    # -- queries for scripts and tests --------------------------------------------------
    def trial_statuses(self) -> list[str]:
        return [status_name(getattr(p, "status", "")) for p in self.controller.schedule()]

    def closeEvent(self, event) -> None:  # noqa: N802
        self.controller.shutdown()
        self.qc.shutdown()
        self.identification.shutdown()
        self.results.shutdown()
        self.setup_panel.lsl.shutdown()
        super().closeEvent(event)
