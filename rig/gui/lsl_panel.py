"""The Lab Streaming Layer streams the window sees, and which of them to record.

Off by default, as ``nmsid run`` without ``--lsl-record``. With "Look for LSL streams"
ticked, the panel lists every stream liblsl resolves (name, type, channels, rate, source
id; ``pylsl.resolve_streams`` in a worker thread: it waits ``wait_s`` and must not hold
the window), and the operator ticks the ones to record. :meth:`LslPanel.wanted` is the
list ``--lsl-record`` takes (stream names); the session records those streams into its
file (:func:`nmsid.rig.lsl.start_recording`). nmsid's own outlets (source id ``nmsid...``)
are listed but cannot be ticked: the session file has their data already.

When pylsl is not installed, or LSL is off, the panel says so and lists nothing. Where
liblsl looks is its configuration's business (``LSLAPICFG``); tests keep it on this
machine (``tests/conftest.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

log = logging.getLogger(__name__)

COLUMNS = ("record", "name", "type", "channels", "rate (Hz)", "source")
#: How long one look for streams waits for answers, s (pylsl's resolve_streams).
RESOLVE_WAIT_S = 1.0
NO_PYLSL = "LSL is unavailable: pylsl is not installed (pip install nmsid[lsl])."
OFF_TEXT = "LSL is off: tick 'Look for LSL streams' to list the streams on the network."


@dataclass(frozen=True)
class StreamRow:
    """One stream as the panel lists it."""

    name: str
    type: str
    channels: int
    rate_Hz: float
    source_id: str

    @property
    def own(self) -> bool:
        """One of nmsid's own outlets (not recorded: the session file holds its data)."""
        return self.source_id.startswith("nmsid")


def resolve_rows(wait_s: float = RESOLVE_WAIT_S) -> list[StreamRow]:
    """The streams liblsl resolves within ``wait_s`` (pylsl imported here: optional)."""
    import pylsl  # optional dependency (the 'lsl' extra)
    rows = [StreamRow(i.name(), i.type(), int(i.channel_count()), float(i.nominal_srate()),
                      i.source_id()) for i in pylsl.resolve_streams(wait_s)]
    return sorted(rows, key=lambda r: (r.name, r.source_id))


def pylsl_available() -> bool:
    try:
        import pylsl  # noqa: F401  (optional dependency: only whether it imports)
    except ImportError:
        return False
    return True


class _Relay(QObject):
    done = Signal(object, object)   # rows or None, error text


class LslPanel(QGroupBox):
    """The streams seen, with a tick per stream to record.

    Parameters
    ----------
    resolve : callable, optional
        ``resolve() -> list[StreamRow]`` (default :func:`resolve_rows`; tests pass their own).
    available : bool, optional
        Whether pylsl can be used (default: whether it imports).
    """

    def __init__(self, resolve: Callable[[], list[StreamRow]] | None = None,
                 available: bool | None = None, parent: QWidget | None = None):
        super().__init__("Lab Streaming Layer: streams to record", parent)
        self._resolve = resolve or resolve_rows
        self.available = pylsl_available() if available is None else bool(available)
        self.rows: list[StreamRow] = []
        self._ticked: set[str] = set()
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="nmsid-lsl-list")
        self._pending: Future | None = None
        self.n_looks = 0
        """Looks for streams finished (each replaces the list)."""
        self._relay = _Relay()
        self._relay.done.connect(self._on_done, Qt.ConnectionType.QueuedConnection)
        self.enabled = QCheckBox("Look for LSL streams")
        self.enabled.setToolTip("List the Lab Streaming Layer streams on the network and "
                                "record the ticked ones into the session file (docs/lsl.md)")
        self.enabled.toggled.connect(self._toggled)
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.clicked.connect(self.refresh)
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.NoSelection)
        self.table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.setMaximumHeight(160)
        self.table.itemChanged.connect(self._item_changed)
        top = QHBoxLayout()
        top.addWidget(self.enabled)
        top.addStretch(1)
        top.addWidget(self.refresh_button)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.status)
        lay.addWidget(self.table)
        self._show_off()

    # -- state ------------------------------------------------------------------------
    def _show_off(self) -> None:
        self.enabled.setEnabled(self.available)
        on = self.available and self.enabled.isChecked()
        self.refresh_button.setEnabled(on)
        self.table.setEnabled(on)
        if not self.available:
            self.status.setText(NO_PYLSL)
        elif not on:
            self.status.setText(OFF_TEXT)

    def _toggled(self, on: bool) -> None:
        self._show_off()
        if on:
            self.refresh()
        else:
            self.rows = []
            self._fill()

    def set_on(self, on: bool) -> None:
        """Tick (or untick) 'Look for LSL streams' (a script or a test)."""
        self.enabled.setChecked(bool(on) and self.available)

    def refresh(self) -> None:
        """Look for streams again (in a worker thread; the list follows)."""
        if not (self.available and self.enabled.isChecked()):
            self._show_off()
            return
        if self._pending is not None and not self._pending.done():
            return
        self.status.setText(f"Looking for LSL streams ({RESOLVE_WAIT_S:g} s) ...")
        resolve, relay = self._resolve, self._relay

        def job():
            try:
                relay.done.emit(resolve(), "")
            except Exception as exc:  # a failing look is shown, never raised
                relay.done.emit(None, f"{type(exc).__name__}: {exc}")
        self._pending = self._pool.submit(job)

    def _on_done(self, rows, error: str) -> None:
        self.n_looks += 1
        if not self.enabled.isChecked():
            return
        if rows is None:
            self.status.setText(f"LSL streams could not be listed ({error}); the session "
                                "runs without LSL recording.")
            self.rows = []
        else:
            self.rows = list(rows)
            recordable = sum(not r.own for r in self.rows)
            self.status.setText(
                f"{len(self.rows)} stream(s) seen, {recordable} can be recorded; tick the "
                "ones to record into the session file." if self.rows else
                "No LSL streams seen. Start the other programs' outlets, then Refresh.")
        self._fill()

    def _fill(self) -> None:
        self.table.blockSignals(True)
        try:
            self.table.setRowCount(len(self.rows))
            for i, r in enumerate(self.rows):
                tick = QTableWidgetItem("" if r.own else "record")
                if r.own:
                    tick.setFlags(Qt.ItemFlag.NoItemFlags)
                    tick.setToolTip("nmsid's own outlet: the session file holds its data")
                else:
                    tick.setFlags(Qt.ItemFlag.ItemIsUserCheckable | Qt.ItemFlag.ItemIsEnabled)
                    tick.setCheckState(Qt.CheckState.Checked if r.name in self._ticked
                                       else Qt.CheckState.Unchecked)
                self.table.setItem(i, 0, tick)
                for col, text in enumerate((r.name, r.type, str(r.channels),
                                            "irregular" if r.rate_Hz == 0 else f"{r.rate_Hz:g}",
                                            r.source_id), start=1):
                    self.table.setItem(i, col, QTableWidgetItem(text))
        finally:
            self.table.blockSignals(False)

    def _item_changed(self, item: QTableWidgetItem) -> None:
        if item.column() != 0 or not 0 <= item.row() < len(self.rows):
            return
        name = self.rows[item.row()].name
        if item.checkState() == Qt.CheckState.Checked:
            self._ticked.add(name)
        else:
            self._ticked.discard(name)

    def set_wanted(self, names) -> None:
        """Tick the streams named (a script or a test; kept for streams not seen yet)."""
        self._ticked = {str(n) for n in names if str(n)}
        self._fill()

    def wanted(self) -> list[str]:
        """The stream names to record (``--lsl-record``'s list; empty: LSL off)."""
        if not (self.available and self.enabled.isChecked()):
            return []
        return sorted(self._ticked)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
