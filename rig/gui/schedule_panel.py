"""Schedule panel: every planned trial with its status, progress and time left.

The table shows one row per planned trial (order of the schedule): the trial's name in
the session file (``t001``, ...; a re-run row shows each attempt), sE, repeat, status
(pending / running / done / aborted) and the abort reason. The running trial is
highlighted and kept in view. Under the table: a progress bar (trials done / total), the
time left on the rig's own clock (the simulator's virtual clock in fast mode), and the
Pause / Resume / Skip / Re-run controls.
"""

from __future__ import annotations

import collections
import re
from collections.abc import Callable, Sequence

from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QBrush, QColor, QFont
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QProgressBar,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from nmsid.rig.gui.theme import Colour
from nmsid.rig.observer import is_rerun_wait

COLUMNS = ("trial", "sE", "repeat", "status", "runs", "reason", "QC")
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


class TrialNames:
    """The session file's names of the trials (``t001``, ...), per schedule row.

    The engine writes every trial it starts (completed or aborted) as the next ``tNNN``;
    the name is predicted when a trial starts and taken from the written trial when it
    ends.

    Examples
    --------
    >>> names = TrialNames()
    >>> names.started(4), names.started(0), names.finished(0, "t002"), names.text(0)
    ('t001', 't002', 't002', 't002')
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self, trials: Sequence[tuple[int, str]] = ()) -> None:
        """Start a session; ``trials``: (schedule index, name) of those already in its file."""
        self.by_index: dict[int, list[str]] = {}
        self.count = 0
        for index, name in trials:
            self.by_index.setdefault(int(index), []).append(name)
            self._seen(name)

    def _seen(self, name: str) -> None:
        m = re.fullmatch(r"t(\d+)", name)
        if m:
            self.count = max(self.count, int(m.group(1)))

    def started(self, index: int) -> str:
        """The name the trial starting now gets in the file."""
        self.count += 1
        name = f"t{self.count:03d}"
        self.by_index.setdefault(int(index), []).append(name)
        return name

    def finished(self, index: int, name: str) -> str:
        """The written trial's name (``name`` from the file; '' keeps the prediction)."""
        names = self.by_index.setdefault(int(index), [])
        if re.fullmatch(r"t\d+", name or ""):
            if names:
                names[-1] = name
            else:
                names.append(name)
            self._seen(name)
        return self.latest(index)

    def latest(self, index: int) -> str:
        """The row's last attempt's name (``#<row>`` if it never ran)."""
        names = self.by_index.get(int(index))
        return names[-1] if names else f"#{int(index) + 1}"

    def text(self, index: int) -> str:
        """Every attempt's name, oldest first (``t003, t007``)."""
        return ", ".join(self.by_index.get(int(index), []))


def time_left_s(statuses: Sequence[str], trial_s: float, rest_s: float,
                in_trial_s: float = 0.0) -> float:
    """Seconds left on the rig's clock: the rest of the running trial, each pending trial
    and the rests between them.

    Examples
    --------
    >>> time_left_s(["done", "running", "pending"], trial_s=15.0, rest_s=60.0, in_trial_s=5.0)
    85.0
    """
    running = sum(st == "running" for st in statuses)
    pending = sum(st == "pending" for st in statuses)
    rests = pending if running else max(0, pending - 1)
    return (pending * trial_s + running * max(0.0, trial_s - in_trial_s)
            + rests * rest_s)


#: The rig clock's pace is measured over this much wall time, s.
PACE_WINDOW_S = 5.0


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
        self.names = TrialNames()
        self._rows_shown: dict[int, tuple] = {}
        """Row -> what it shows now (rows whose content did not change are not touched)."""
        self._scrolled_to = -1
        self.in_trial_s = 0.0
        self.realtime = True
        self._clock: collections.deque[tuple[float, float]] = collections.deque()
        """(wall s, rig clock s) readings of the last ``PACE_WINDOW_S``."""
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
        for col in range(len(COLUMNS)):  # fitted when a column's text changes (set_schedule):
            # ResizeToContents re-measured every row on each change, ~30 ms a refresh
            hdr.setSectionResizeMode(col, QHeaderView.ResizeMode.Interactive)
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
            self._rows_shown = {}
        bold = QFont()
        bold.setBold(True)
        normal = QFont()
        changed_cols: set[int] = set()
        self.statuses = []
        for i, (sE, repeat, status, reason) in enumerate(rows):
            if i == self.current_index and status == "running":
                shown = "running"
            else:
                shown = status
            self.statuses.append(shown)
            runs = str(attempts[i]) if attempts[i] else ""
            decision, why = self.qc.get(i, ("", ""))
            values = (self.names.text(i), f"{sE:.2f}", str(repeat), shown, runs, reason,
                      decision if shown in ("done", "completed") else "")
            key = (values, why, i == self.current_index)
            before = self._rows_shown.get(i)
            if before == key:
                continue  # a row costs ~1 ms to restyle: only the changed ones
            if before is None or before[2] != key[2]:  # bold or not: widths change
                changed_cols.update(range(len(COLUMNS)))
            self._rows_shown[i] = key
            colour = QColor(Colour.STATUS.get(shown, "#ffffff"))
            for col, text in enumerate(values):
                item = self.table.item(i, col)
                if item is None:
                    item = QTableWidgetItem()
                    self.table.setItem(i, col, item)
                if item.text() != text:
                    item.setText(text)
                    changed_cols.add(col)
                qc_col = col == COLUMNS.index("QC")
                item.setBackground(QBrush(QColor(QC_COLOURS.get(text, colour.name()))
                                          if qc_col else colour))
                item.setFont(bold if i == self.current_index else normal)
                if col == COLUMNS.index("reason"):
                    item.setToolTip(reason)
                elif qc_col:
                    item.setToolTip(why)
        for col in sorted(changed_cols - {COLUMNS.index("reason")}):
            self.table.resizeColumnToContents(col)
        done = sum(s in ("done", "completed", "skipped") for s in self.statuses)
        self.progress.setMaximum(max(1, len(rows)))
        self.progress.setValue(done)
        self._show_time_left()
        item = self.table.item(self.current_index, 0) if 0 <= self.current_index < len(rows) \
            else None
        if item is not None and self._scrolled_to != self.current_index:
            self._scrolled_to = self.current_index
            self.table.scrollToItem(item, QAbstractItemView.ScrollHint.EnsureVisible)
        self._selection_changed()

    def reset_session(self, trials: Sequence[tuple[int, str]] = ()) -> None:
        """A new session: no verdicts, names (``trials``: those already in its file), clock."""
        self.qc.clear()
        self.names.reset(trials)
        self._rows_shown = {}
        self._scrolled_to = -1
        self._clock.clear()
        self.in_trial_s, self.realtime = 0.0, True

    def set_clock(self, rig_s: float | None, wall_s: float, in_trial_s: float,
                  realtime: bool = True) -> None:
        """The rig clock read now (``rig_s``, s; None: no clock) at wall time ``wall_s``,
        and how far the running trial is (s on the rig's clock). With a clock that is not
        real time (the simulator's fast clock) the label also gives the wall time left at
        the pace measured over the last ``PACE_WINDOW_S``."""
        self.in_trial_s, self.realtime = float(in_trial_s), bool(realtime)
        if rig_s is not None:
            self._clock.append((float(wall_s), float(rig_s)))
            while len(self._clock) > 2 and self._clock[0][0] < wall_s - PACE_WINDOW_S:
                self._clock.popleft()
        self._show_time_left()

    def pace(self) -> float | None:
        """Rig-clock seconds per wall second lately (None: not measured yet)."""
        if len(self._clock) < 2:
            return None
        (w0, r0), (w1, r1) = self._clock[0], self._clock[-1]
        return (r1 - r0) / (w1 - w0) if w1 - w0 > 0.2 else None

    def _show_time_left(self) -> None:
        if not self.statuses:
            return
        left = time_left_s(self.statuses, self.trial_s, self.rest_s, self.in_trial_s)
        text = f"time left: ~{format_duration(left)}"
        if not self.realtime:
            pace = self.pace()
            text += " on the rig's clock (fast clock" + (
                f", {pace:.0f}x real time: ~{format_duration(left / pace)} wall)"
                if pace is not None and pace > 0 else ")")
        self.time_left.setText(text)

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
