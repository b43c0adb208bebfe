"""The operator's window: one place to run a whole session.

Layout: the safety strip (E-STOP, interlock lights, state, trip banner, RE-ARM) across the
top, always visible; under it, tabs (Setup, Calibration, Live trial, Identification,
Results) on the left and the schedule and the event log on the right.

Threads: the engine runs in the controller's worker thread; its notifications arrive as
queued signals (slots below run in the GUI thread); chunks go to the live buffer that the
plot timer reads. Identification and model selection run in worker pools. The methods
``start_session``, ``confirm_calibration``, ``press_estop``, ``rearm``, ``pause``,
``resume``, ``skip``, ``rerun``, ``end_session``, ``add_note`` and ``save_screenshot`` are the Python API a
script or a test uses to drive the window as an operator would.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

from PySide6.QtCore import Qt, QTimer

import nmsid.rig.gui.qt_compat  # noqa: F401  (before any signal is emitted)
from PySide6.QtWidgets import (QLabel, QMainWindow, QSplitter, QTabWidget, QVBoxLayout,
                               QWidget)

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
from nmsid.rig.gui.session_controller import (DevicesFactory, SessionController,
                                              load_session_config)
from nmsid.rig.gui.setup_panel import SessionRequest, SetupPanel
from nmsid.rig.states import State

log = logging.getLogger(__name__)

INTERLOCK_POLL_MS = 200
LIVE_WINDOW_S = 10.0


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
        self.setWindowTitle("nmsid - FES identification session")
        self.auto_tabs = auto_tabs
        self.config_transform = config_transform
        self.state = State.IDLE
        self.trip_reason = ""
        self.current_index = -1
        self.run_result = None
        self.run_error: BaseException | None = None
        self.session_finished = False
        self._calibration_known = False

        self.buffer = LiveBuffer(window_s=live_window_s)
        self.signals = EngineSignals()
        self.controller = SessionController(self.signals, self.buffer,
                                            devices_factory=devices_factory,
                                            engine_factory=engine_factory)

        self.safety = SafetyPanel(on_estop=self.press_estop, on_rearm=self.rearm)
        self.setup_panel = SetupPanel(on_start=self._start_request)
        self.calibration_panel = CalibrationPanel(on_confirm=self._confirm_calibration)
        self.live = LivePlots(self.buffer)
        self.identification = IdentificationPanel(
            identify=identify if identify is not None else analysis_hooks.identify_level)
        self.results = ResultsPanel(
            select_models=select_models if select_models is not None
            else analysis_hooks.select_models)
        self.schedule_panel = SchedulePanel(on_pause=self.pause, on_resume=self.resume,
                                            on_skip=self.skip, on_rerun=self.rerun,
                                            on_end=self.end_session,
                                            on_repeat=self.repeat_excluded)
        self._qc_trials: dict[float, dict] = {}
        """sE -> {schedule index: the latest completed trial}, for the quality control."""
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
        s = self.signals
        s.state_changed.connect(self._on_state, q)
        s.event_logged.connect(self._on_event, q)
        s.calibration_step.connect(self.calibration_panel.add_step, q)
        s.calibration_result.connect(self._on_calibration_result, q)
        s.trial_started.connect(self._on_trial_started, q)
        s.trial_finished.connect(self._on_trial_finished, q)
        s.level_completed.connect(self._on_level_completed, q)
        s.finished.connect(self._on_finished, q)
        s.run_ended.connect(self._on_run_ended, q)

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
        self.controller.start(request, config=config)
        engine = self.controller.engine
        self._calibration_known = bool(request.resume and
                                       getattr(engine, "calibration", None) is not None)
        used = getattr(engine, "config", config)
        self.safety.set_weakened(used.weakened_safety())
        p = used.protocol
        self.schedule_panel.set_timing(p.trial_s, p.rest_s)
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
        self._qc_trials = {}
        self.schedule_panel.qc.clear()
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
        """The E-STOP button, Space or Escape: stop output now and latch the interlock."""
        engaged = self.controller.estop("operator E-stop (GUI)")
        if not engaged:
            self.event_log.append("E-STOP pressed (no session running; output is off)")

    def rearm(self) -> None:
        self.controller.rearm()

    def pause(self) -> None:
        self.controller.pause()

    def resume(self) -> None:
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
    def _on_state(self, old, new, reason: str) -> None:
        self.state = new
        name = getattr(new, "value", str(new))
        if new is State.TRIPPED:
            self.trip_reason = reason
        self.safety.set_state(name, reason)
        self.schedule_panel.set_state(name, reason)
        self._refresh_schedule()
        self._poll_engine()
        if new is State.CALIBRATING:
            self._switch(Tab.CALIBRATION)
        elif new is State.STIMULATING:
            self._switch(Tab.LIVE)

    def _on_event(self, event) -> None:
        self.event_log.append(event)
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

    def _on_trial_started(self, index: int, planned) -> None:
        self.current_index = index
        sE, repeat, _, _ = planned_fields(planned)
        cfg = getattr(self.controller.engine, "config", None) or self.controller.config
        self.live.set_title(f"Trial {index + 1}: sE = {sE:.2f}, repeat {repeat}",
                            duration_s=cfg.protocol.trial_s if cfg is not None else None)
        self._refresh_schedule()

    def _on_trial_finished(self, index: int, trial) -> None:
        status = getattr(trial, "status", "")
        reason = getattr(trial, "abort_reason", "")
        sE, repeat = getattr(trial, "sE", float("nan")), getattr(trial, "repeat", 0)
        verdict = self._judge(index, trial) if status == "completed" else None
        self.live.set_title(f"Trial {index + 1}: sE = {sE:.2f}, repeat {repeat}: {status}"
                            + (f" ({reason})" if reason else "")
                            + (f"  |  QC: {verdict[0]}" + (f" ({verdict[1]})" if verdict[1]
                                                           else "") if verdict else ""))
        self._refresh_schedule()

    def _judge(self, index: int, trial) -> tuple[str, str] | None:
        """QC of a completed trial against the completed repeats of its level so far; the
        verdicts of the level's earlier trials are updated too (a third repeat can decide
        what two could not)."""
        if getattr(trial, "force_N", None) is None:
            return None
        level = self._qc_trials.setdefault(round(float(trial.sE), 9), {})
        level[index] = trial
        try:
            verdicts = analysis_hooks.trial_verdicts(level)
        except (ValueError, ArithmeticError) as exc:
            log.warning("quality control of trial %d failed: %s", index + 1, exc)
            return None
        for i, (decision, why) in verdicts.items():
            self.schedule_panel.set_qc(i, decision, why)
        decision, why = verdicts.get(index, ("", ""))
        if decision == "excluded":
            self.event_log.append(f"QC: trial {index + 1} (sE {trial.sE:.2f}, repeat "
                                  f"{trial.repeat}) excluded: {why}. 'Repeat excluded' runs "
                                  "it again.")
        return verdicts.get(index)

    def _on_level_completed(self, sE: float, trials: list) -> None:
        self.identification.submit_level(sE, trials)

    def _on_finished(self, path: str) -> None:
        self.session_finished = True
        self._refresh_schedule()

    def _on_run_ended(self, summary, error) -> None:
        self.run_result, self.run_error = summary, error
        self._poll_engine()
        self._refresh_schedule()
        self.setup_panel.new_session()
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
        if self.controller.engine is None:
            return
        try:
            self.safety.set_interlock(self.controller.interlock_status())
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
        self.identification.shutdown()
        self.results.shutdown()
        super().closeEvent(event)
