"""The bridge from the engine thread to the GUI thread.

:class:`QtEngineObserver` is the engine's observer. Its methods run in the ENGINE thread,
so they only (a) copy acquisition chunks into a :class:`~nmsid.rig.gui.live_buffer.LiveBuffer`
and (b) emit Qt signals of :class:`EngineSignals`, which live in the GUI thread and are
connected with ``Qt.QueuedConnection``: the slots run later in the GUI thread. Nothing
here touches a widget or waits for the GUI.
"""

from __future__ import annotations

import logging

from PySide6.QtCore import QObject, Signal

import nmsid.rig.gui.qt_compat  # noqa: F401  (before any signal is emitted)

from nmsid.rig.engine import EngineObserver
from nmsid.rig.gui.live_buffer import LiveBuffer

log = logging.getLogger(__name__)


class EngineSignals(QObject):
    """Qt signals carrying engine notifications into the GUI thread."""

    state_changed = Signal(object, object, str)      # old, new, reason
    event_logged = Signal(object)   # protocols.session_file.Event-like (not `event`: QObject's)
    calibration_step = Signal(str, float, float)     # muscle, current_mA, force_N
    calibration_result = Signal(object)              # Calibration
    trial_started = Signal(int, object)              # schedule index, PlannedTrial
    trial_finished = Signal(int, object)             # schedule index, Trial
    level_completed = Signal(float, object)          # sE, list[Trial]
    finished = Signal(str)                           # session file path
    run_ended = Signal(object, object)               # RunSummary or None, exception or None


class QtEngineObserver(EngineObserver):
    """Engine observer that only enqueues: chunk data to a buffer, the rest as signals.

    Parameters
    ----------
    signals : EngineSignals
        Created in the GUI thread; its receivers use queued connections.
    buffer : LiveBuffer
        Filled with every chunk of the running trial.
    """

    def __init__(self, signals: EngineSignals, buffer: LiveBuffer):
        self.signals = signals
        self.buffer = buffer

    def on_state(self, old, new, reason="") -> None:
        self.signals.state_changed.emit(old, new, str(reason or ""))

    def on_event(self, event) -> None:
        self.signals.event_logged.emit(event)

    def on_calibration_step(self, muscle, current_mA, force_N) -> None:
        self.signals.calibration_step.emit(str(getattr(muscle, "value", muscle)),
                                           float(current_mA), float(force_N))

    def on_calibration_result(self, calibration) -> None:
        self.signals.calibration_result.emit(calibration)

    def on_trial_started(self, index, planned) -> None:
        self.buffer.start_trial(index)
        self.signals.trial_started.emit(int(index), planned)

    def on_chunk(self, index, start_index, force_N, rE, I_ext_mA, I_flex_mA) -> None:
        self.buffer.append(index, start_index, force_N, rE, I_ext_mA, I_flex_mA)

    def on_target(self, index, start_index, target_N) -> None:
        self.buffer.set_target(index, start_index, target_N)

    def on_trial_finished(self, index, trial) -> None:
        self.signals.trial_finished.emit(int(index), trial)

    def on_level_completed(self, sE, trials) -> None:
        self.signals.level_completed.emit(float(sE), list(trials))

    def on_finished(self, path) -> None:
        self.signals.finished.emit(str(path))
