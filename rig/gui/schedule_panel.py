"""Schedule panel: every planned trial with its status, progress and time left.

The table shows one row per planned trial (order of the schedule): sE, repeat, status
(pending / running / done / aborted) and the abort reason. The running trial is
highlighted and kept in view. Under the table: a progress bar (trials done / total), the
estimated time left, and the Pause / Resume / Skip / Re-run controls.
"""

from __future__ import annotations

from typing import Callable, Sequence

from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QBrush, QColor, QFont
from PySide6.QtWidgets import (QAbstractItemView, QHBoxLayout, QHeaderView, QLabel,
                               QProgressBar, QPushButton, QTableWidget, QTableWidgetItem,
                               QVBoxLayout, QWidget)

from nmsid.rig.gui.theme import Colour
from nmsid.rig.observer import is_rerun_wait

COLUMNS = ("#", "sE", "repeat", "status", "runs", "reason", "QC")
QC_COLOURS = {"used": "#d8f3dc", "repaired": "#fff3b0", "excluded": "#ffb3b3"}
END_TEXT = "End session"
#: The second click of End session must come within this time, ms.
END_CONFIRM_MS = 4000


def status_name(value) -> str:
    """Lower-case status name for an enum member or a string."""
    return str(getattr(value, "value", value)).lower()


def planned_fields(planned) -> tuple[float, int, str, str]:
    """(sE, repeat, status, reason) of a planned trial, whatever its exact class."""
    sE = float(getattr(planned, "sE", float("nan")))
    repeat = int(getattr(planned, "repeat", 0))
    status = status_name(getattr(planned, "status", "pending"))
    reason = str(getattr(planned, "reason", "") or getattr(planned, "abort_reason", "") or "")
    return sE, repeat, status, reason


def planned_attempts(planned) -> int:
    """How many times the trial was started (re-runs count)."""
    return int(getattr(planned, "attempts", 0) or 0)


def format_duration(seconds: float) -> str:
    """``1 h 02 min``, ``12 min 05 s`` or ``40 s``."""
    s = max(0, int(round(seconds)))
    if s >= 3600:
        return f"{s // 3600} h {(s % 3600) // 60:02d} min"
    if s >= 60:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s} s"


class SchedulePanel(QWidget):
    """Table of planned trials with progress and the run controls.

    Parameters
    ----------
    on_pause, on_resume, on_skip : callable
        Called with no argument when the operator presses the button.
    on_rerun : callable
        Called with the schedule index of the selected aborted trial.
    on_end : callable, optional
        Called when the operator ends the session early (two clicks within
        ``END_CONFIRM_MS``).
    """

    def __init__(self, on_pause: Callable[[], None], on_resume: Callable[[], None],
                 on_skip: Callable[[], None], on_rerun: Callable[[int], None],
                 on_end: Callable[[], None] | None = None,
                 on_repeat: Callable[[int], None] | None = None,
                 parent: QWidget | None = None):
        super().__init__(parent)
        self._on_rerun = on_rerun
        self._on_repeat = on_repeat
        self.qc: dict[int, tuple[str, str]] = {}
        """Schedule index -> (QC decision, reasons) of each completed trial."""
        self._on_end = on_end
        self.trial_s = 15.0
        self.rest_s = 60.0
        self.current_index = -1
        self.statuses: list[str] = []
        self.waiting_for_rerun = False
        """The engine waits, after the schedule, for a re-run or the end of the session."""

        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        hdr = self.table.horizontalHeader()
        for col in range(len(COLUMNS)):
            hdr.setSectionResizeMode(col, QHeaderView.ResizeMode.ResizeToContents)
        hdr.setSectionResizeMode(COLUMNS.index("reason"), QHeaderView.ResizeMode.Stretch)
        self.table.itemSelectionChanged.connect(self._selection_changed)

        self.progress = QProgressBar()
        self.progress.setFormat("%v / %m trials")
        self.time_left = QLabel("time left: -")
        self.pause_button = QPushButton("Pause")
        self.resume_button = QPushButton("Resume")
        self.skip_button = QPushButton("Skip trial")
        self.rerun_button = QPushButton("Re-run aborted")
        self.rerun_button.setToolTip("Re-run the selected aborted trial (or the first "
                                     "aborted one if none is selected)")
        self.repeat_button = QPushButton("Repeat excluded")
        self.repeat_button.setToolTip("Run a trial that the quality control excluded once "
                                      "more while the participant is still there (the "
                                      "recorded one stays in the file)")
        self.end_button = QPushButton(END_TEXT)
        self.end_button.setToolTip("End the session now (output off); press twice. The "
                                   "file keeps everything and can be resumed later.")
        self._end_armed = False
        self._end_timer = QTimer(self)
        self._end_timer.setSingleShot(True)
        self._end_timer.timeout.connect(self._disarm_end)
        for b in (self.pause_button, self.resume_button, self.skip_button, self.rerun_button,
                  self.repeat_button, self.end_button):
            b.setFocusPolicy(Qt.FocusPolicy.NoFocus)
            b.setEnabled(False)
        self.pause_button.clicked.connect(on_pause)
        self.resume_button.clicked.connect(on_resume)
        self.skip_button.clicked.connect(on_skip)
        self.rerun_button.clicked.connect(self._rerun_clicked)
        self.repeat_button.clicked.connect(self._repeat_clicked)
        self.end_button.clicked.connect(self._end_clicked)

        controls = QHBoxLayout()
        for b in (self.pause_button, self.resume_button, self.skip_button, self.rerun_button,
                  self.repeat_button, self.end_button):
            controls.addWidget(b)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.table, 1)
        prog = QHBoxLayout()
        prog.addWidget(self.progress, 1)
        prog.addWidget(self.time_left)
        lay.addLayout(prog)
        lay.addLayout(controls)

    # -- data ---------------------------------------------------------------------------
    def set_timing(self, trial_s: float, rest_s: float) -> None:
        """Durations used for the time-left estimate, s."""
        self.trial_s, self.rest_s = float(trial_s), float(rest_s)

    def set_schedule(self, schedule: Sequence, current_index: int | None = None) -> None:
        """Show the engine's schedule (list of planned trials) and highlight the current."""
        if current_index is not None:
            self.current_index = current_index
        rows = [planned_fields(p) for p in schedule]
        attempts = [planned_attempts(p) for p in schedule]
        if self.table.rowCount() != len(rows):
            self.table.setRowCount(len(rows))
        bold = QFont()
        bold.setBold(True)
        normal = QFont()
        self.statuses = []
        for i, (sE, repeat, status, reason) in enumerate(rows):
            if i == self.current_index and status == "running":
                shown = "running"
            else:
                shown = status
            self.statuses.append(shown)
            runs = str(attempts[i]) if attempts[i] else ""
            decision, why = self.qc.get(i, ("", ""))
            values = (str(i + 1), f"{sE:.2f}", str(repeat), shown, runs, reason,
                      decision if shown in ("done", "completed") else "")
            colour = QColor(Colour.STATUS.get(shown, "#ffffff"))
            for col, text in enumerate(values):
                item = self.table.item(i, col)
                if item is None:
                    item = QTableWidgetItem()
                    self.table.setItem(i, col, item)
                if item.text() != text:
                    item.setText(text)
                qc_col = col == COLUMNS.index("QC")
                item.setBackground(QBrush(QColor(QC_COLOURS.get(text, colour.name()))
                                          if qc_col else colour))
                item.setFont(bold if i == self.current_index else normal)
                if col == COLUMNS.index("reason"):
                    item.setToolTip(reason)
                elif qc_col:
                    item.setToolTip(why)
        done = sum(s in ("done", "completed", "skipped") for s in self.statuses)
        self.progress.setMaximum(max(1, len(rows)))
        self.progress.setValue(done)
        left = sum(s in ("pending", "running") for s in self.statuses)
        if rows:
            self.time_left.setText(
                f"time left: ~{format_duration(left * self.trial_s + max(0, left - 1) * self.rest_s)}")
        item = self.table.item(self.current_index, 0) if 0 <= self.current_index < len(rows) \
            else None
        if item is not None:
            self.table.scrollToItem(item, QAbstractItemView.ScrollHint.EnsureVisible)
        self._selection_changed()

    def set_state(self, state: str, reason: str = "") -> None:
        """Enable the controls that make sense in the engine state. In the engine's wait
        for a re-run after the schedule (``paused`` with the reason of
        :func:`nmsid.rig.observer.rerun_wait_reason`) only Re-run aborted and End session do
        something: Resume and Skip are off."""
        self._state = state
        self.waiting_for_rerun = is_rerun_wait(state, reason)
        running = state in ("calibrating", "armed", "stimulating", "resting")
        self.pause_button.setEnabled(running)
        self.resume_button.setEnabled(state == "paused" and not self.waiting_for_rerun)
        self.skip_button.setEnabled(state in ("armed", "stimulating", "resting", "paused")
                                    and not self.waiting_for_rerun)
        self.end_button.setEnabled(self._on_end is not None and state not in
                                   ("idle", "finished"))
        if state == "finished":
            self._disarm_end()
        self._selection_changed()

    # -- ending early ---------------------------------------------------------------------
    def _end_clicked(self) -> None:
        if not self._end_armed:
            self._end_armed = True
            self.end_button.setText("Click again to END")
            self.end_button.setStyleSheet("background: #e08000; color: white;")
            self._end_timer.start(END_CONFIRM_MS)
            return
        self._disarm_end()
        if self._on_end is not None:
            self._on_end()

    def _disarm_end(self) -> None:
        self._end_armed = False
        self._end_timer.stop()
        self.end_button.setText(END_TEXT)
        self.end_button.setStyleSheet("")

    # -- re-run -----------------------------------------------------------------------
    def set_qc(self, index: int, decision: str, reasons: str) -> None:
        """Show the quality control's verdict on the completed trial at ``index``."""
        self.qc[int(index)] = (decision, reasons)
        self._selection_changed()

    def excluded_indices(self) -> list[int]:
        """Completed trials the quality control excluded (not yet repeated)."""
        return [i for i, (d, _) in sorted(self.qc.items()) if d == "excluded"
                and i < len(self.statuses) and self.statuses[i] in ("done", "completed")]

    def aborted_indices(self) -> list[int]:
        return [i for i, s in enumerate(self.statuses) if s == "aborted"]

    def selected_index(self) -> int | None:
        rows = self.table.selectionModel().selectedRows() if self.table.selectionModel() else []
        return rows[0].row() if rows else None

    def _selection_changed(self) -> None:
        state = getattr(self, "_state", "idle")
        ok_state = state in ("armed", "stimulating", "resting", "paused", "tripped")
        self.rerun_button.setEnabled(ok_state and bool(self.aborted_indices()))
        self.repeat_button.setEnabled(ok_state and self._on_repeat is not None
                                      and bool(self.excluded_indices()))

    def _repeat_clicked(self) -> None:
        sel = self.selected_index()
        excluded = self.excluded_indices()
        if self._on_repeat is None or not excluded:
            return
        self._on_repeat(sel if sel in excluded else excluded[0])

    def _rerun_clicked(self) -> None:
        sel = self.selected_index()
        aborted = self.aborted_indices()
        if sel is not None and sel in aborted:
            self._on_rerun(sel)
        elif aborted:
            self._on_rerun(aborted[0])
