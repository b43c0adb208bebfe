"""Event log pane: every engine event as it happens, and the operator's notes.

A note typed here goes to ``engine.commands.add_note`` (written to the session file's events);
the engine echoes it back as an event, so the pane shows exactly what the file holds.
"""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtGui import QTextCursor
from PySide6.QtWidgets import (
    QHBoxLayout,
    QLineEdit,
    QPlainTextEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

MAX_LINES = 5000


def event_line(event) -> str:
    """``01:30:02  estop  operator E-stop`` for an Event-like object (or a string)."""
    if isinstance(event, str):
        return event
    utc = str(getattr(event, "utc", "") or "")
    kind = getattr(event, "kind", "")
    kind = str(getattr(kind, "value", kind))
    detail = str(getattr(event, "detail", "") or "")
    time_part = utc[11:19] if len(utc) >= 19 else utc
    return f"{time_part}  {kind:<14} {detail}".rstrip()


class EventLog(QWidget):
    """Read-only log with a note field under it.

    Parameters
    ----------
    on_note : callable
        Called with the note text when the operator adds a note.
    """

    def __init__(self, on_note: Callable[[str], None], parent: QWidget | None = None):
        super().__init__(parent)
        self._on_note = on_note
        self.view = QPlainTextEdit()
        self.view.setReadOnly(True)
        self.view.setMaximumBlockCount(MAX_LINES)
        self.view.setStyleSheet("font-family: monospace; font-size: 11px;")
        self.note = QLineEdit()
        self.note.setPlaceholderText("Operator note (Enter to add to the session file)")
        self.note.returnPressed.connect(self.add_note)
        self.note_button = QPushButton("Add note")
        self.note_button.clicked.connect(self.add_note)
        row = QHBoxLayout()
        row.addWidget(self.note, 1)
        row.addWidget(self.note_button)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.view, 1)
        lay.addLayout(row)
        self.lines: list[str] = []

    def append(self, event) -> None:
        line = event_line(event)
        self.lines.append(line)
        del self.lines[:-MAX_LINES]
        self.view.appendPlainText(line)
        self.view.moveCursor(QTextCursor.MoveOperation.End)

    def add_note(self, text: str | None = None) -> None:
        text = (text if isinstance(text, str) else self.note.text()).strip()
        if not text:
            return
        self._on_note(text)
        self.note.clear()
