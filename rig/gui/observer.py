"""The bridge from the engine thread to the GUI thread.

:class:`QtEngineObserver` is the engine's observer. Its methods run in the ENGINE thread,
so they only (a) copy acquisition chunks into a :class:`~nmsid.rig.gui.live_buffer.LiveBuffer`
and (b) post the other notifications, in order, to a :class:`Mailbox`. When the mailbox
goes from empty to not empty it emits :attr:`EngineSignals.notified` (a queued
connection); the window then takes everything posted so far in one step and shows the
latest state. However fast the engine runs (the simulator's fast clock), the GUI thread
handles one batch per wake-up instead of one queued call per notification, so the display
never falls behind: plot frames and samples are dropped, notifications never are.
Nothing here touches a widget or waits for the GUI.
"""

from __future__ import annotations

import logging
import threading

from PySide6.QtCore import QObject, Signal

import nmsid.rig.gui.qt_compat  # noqa: F401  (before any signal is emitted)
from nmsid.rig.engine import EngineObserver
from nmsid.rig.gui.live_buffer import LiveBuffer

log = logging.getLogger(__name__)


class EngineSignals(QObject):
    """Qt signals carrying engine notifications into the GUI thread."""

    notified = Signal()                              # the mailbox has something new
    run_ended = Signal(object, object)               # RunSummary or None, exception or None


class Mailbox:
    """The engine's notifications in order, for the GUI thread to take in batches.

    Each item is ``(name, args)``, ``name`` one of ``state``, ``event``,
    ``calibration_step``, ``calibration_result``, ``trial_started``, ``trial_finished``,
    ``level_completed``, ``finished``.

    Examples
    --------
    >>> box = Mailbox()
    >>> box.put("state", ("armed", "stimulating", "")), box.put("event", ("e",))
    (True, False)
    >>> box.pending(), [name for name, _ in box.take()], box.take(), box.pending()
    (2, ['state', 'event'], [], 0)
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list[tuple[str, tuple]] = []
        self.n_posted = 0
        """Notifications posted since construction."""

    def put(self, name: str, args: tuple) -> bool:
        """Post one notification (any thread); True if the mailbox was empty."""
        with self._lock:
            was_empty = not self._items
            self._items.append((name, args))
            self.n_posted += 1
        return was_empty

    def pending(self) -> int:
        """How many notifications wait (any thread; a glance, no copy)."""
        return len(self._items)

    def take(self) -> list[tuple[str, tuple]]:
        """Everything posted so far, oldest first (GUI thread)."""
        with self._lock:
            items, self._items = self._items, []
        return items


class QtEngineObserver(EngineObserver):
    """Engine observer that only enqueues: chunk data to a buffer, the rest to a mailbox.

    Parameters
    ----------
    signals : EngineSignals
        Created in the GUI thread; its receivers use queued connections.
    buffer : LiveBuffer
        Filled with every chunk of the running trial.
    mailbox : Mailbox, optional
        Where the notifications go (default: a new one, ``self.mailbox``).
    """

    def __init__(self, signals: EngineSignals, buffer: LiveBuffer,
                 mailbox: Mailbox | None = None):
        self.signals = signals
        self.buffer = buffer
        self.mailbox = mailbox if mailbox is not None else Mailbox()

    def _post(self, name: str, *args) -> None:
        if self.mailbox.put(name, args):
            self.signals.notified.emit()

    def on_state(self, old, new, reason="") -> None:
        self._post("state", old, new, str(reason or ""))

    def on_event(self, event) -> None:
        self._post("event", event)

    def on_calibration_step(self, muscle, current_mA, force_N) -> None:
        self._post("calibration_step", str(getattr(muscle, "value", muscle)),
                   float(current_mA), float(force_N))

    def on_calibration_result(self, calibration) -> None:
        self._post("calibration_result", calibration)

    def on_trial_started(self, index, planned) -> None:
        self.buffer.start_trial(index)
        self._post("trial_started", int(index), planned)

    def on_chunk(self, index, start_index, force_N, rE, I_ext_mA, I_flex_mA) -> None:
        self.buffer.append(index, start_index, force_N, rE, I_ext_mA, I_flex_mA)

    def on_target(self, index, start_index, target_N) -> None:
        self.buffer.set_target(index, start_index, target_N)

    def on_trial_finished(self, index, trial) -> None:
        self._post("trial_finished", int(index), trial)

    def on_level_completed(self, sE, trials) -> None:
        self._post("level_completed", float(sE), list(trials))

    def on_finished(self, path) -> None:
        self._post("finished", str(path))
