"""End-of-session results: model selection across sE, as the paper's tables and figures.

When the session finishes, :class:`ResultsPanel` runs the model selection in a worker
thread (``select_models(session_path) -> SelectionView``) and then shows, per parameter
(Kp, wn, zeta), the AICc of the linear, quadratic and exponential models with the selected
one marked (the paper's Tables 1, 4, 7 for one participant) and the identified values
against sE with the fitted curves (Figures 4-6). The same tables are written beside the
session file (``<stem>-analysis/``) as CSV with a PNG of the panel, beside the analysis'
own report (tables, twin, figures) that the hook writes there.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHeaderView,
    QLabel,
    QPlainTextEdit,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from nmsid.rig.gui.memory import release_freed_memory
from nmsid.rig.gui.theme import Colour

log = logging.getLogger(__name__)

MODEL_COLOURS = {"linear": "#1f77b4", "quadratic": "#d62728", "exponential": "#2ca02c"}


def model_curve(model: str, coefficients, sE) -> np.ndarray:
    """Evaluate a parameter curve of sE (layout of ``docs/twin-file.md``).

    Examples
    --------
    >>> model_curve("quadratic", [1.0, 2.0, 3.0], np.array([0.0, 1.0])).tolist()
    [1.0, 6.0]
    """
    sE = np.asarray(sE, dtype=float)
    c = [float(v) for v in coefficients]
    if model == "linear":
        return c[0] + c[1] * sE
    if model == "quadratic":
        return c[0] + c[1] * sE + c[2] * sE ** 2
    if model == "exponential":
        return c[0] * np.exp(c[1] * sE)
    if model == "constant":
        return np.full_like(sE, c[0])
    raise ValueError(f"unknown parameter model {model!r}; known: linear, quadratic, "
                     "exponential, constant")


@dataclass(frozen=True)
class ModelFit:
    model: str
    aicc: float
    coefficients: tuple[float, ...]


@dataclass
class ParameterSelection:
    """One parameter's values against sE and its candidate models."""

    name: str
    units: str
    sE: np.ndarray
    values: np.ndarray
    fits: list[ModelFit]
    selected: str
    figure: str = ""
    """The paper's figure this corresponds to (``Figure 4``)."""
    trend: str = ""
    """The selected curve's shape in words (``increasing, convex``)."""
    excluded_sE: np.ndarray = field(default_factory=lambda: np.empty(0))
    excluded_values: np.ndarray = field(default_factory=lambda: np.empty(0))
    """Points left out of the comparison (IQR outliers), drawn hollow."""


@dataclass
class SelectionView:
    """What the panel shows: the parameters, and where the report files went."""

    parameters: list[ParameterSelection]
    saved: list[Path] = field(default_factory=list)
    note: str = ""
    tables_text: str = ""
    """The analysis' tables as text (the paper's Tables 1-9 for this session)."""
    problems: list[str] = field(default_factory=list)
    """What the analysis could not do or explain (also in ``problems.txt``), shown in full."""


class _Relay(QObject):
    done = Signal(object, object)


class ResultsPanel(QWidget):
    """Model-selection tables and parameter-vs-sE figures.

    Parameters
    ----------
    select_models : callable
        ``select_models(session_path) -> SelectionView``, run in a worker thread.
    """

    def __init__(self, select_models: Callable | None = None, parent: QWidget | None = None):
        super().__init__(parent)
        self.select_models = select_models
        self.view: SelectionView | None = None
        self.error: str = ""
        self.saved: list[Path] = []
        self.busy = False
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="nmsid-results")
        self._relay = _Relay()
        self._relay.done.connect(self._on_done, Qt.ConnectionType.QueuedConnection)
        self._session_path: Path | None = None
        self.status = QLabel("Model selection appears here when the session finishes.")
        self.status.setWordWrap(True)
        self.table = QTableWidget(0, 6)
        self.table.setHorizontalHeaderLabels(
            ("parameter", "AICc linear", "AICc quadratic", "AICc exponential", "selected",
             "selected curve (trend)"))
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.table.setMaximumHeight(130)
        self.problems = QPlainTextEdit()
        self.problems.setObjectName("problems")
        self.problems.setReadOnly(True)
        self.problems.setMaximumHeight(110)
        self.problems.setStyleSheet(f"color: {Colour.FAULT}; font-size: 11px;")
        self.problems.setVisible(False)
        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground("w")
        self.plots: dict[str, pg.PlotItem] = {}
        self.tables_text = QPlainTextEdit()
        self.tables_text.setReadOnly(True)
        self.tables_text.setStyleSheet("font-family: monospace; font-size: 11px;")
        self.views = QTabWidget()
        self.views.addTab(self.graphics, "Figures 4-6: parameters vs sE")
        self.views.addTab(self.tables_text, "Tables")
        self.views.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.status)
        lay.addWidget(self.problems)
        lay.addWidget(self.table)
        lay.addWidget(self.views, 1)

    def reset(self) -> None:
        """Forget the previous session's results."""
        self.view = None
        self.error = ""
        self.saved = []
        self.table.setRowCount(0)
        self.problems.setPlainText("")
        self.problems.setVisible(False)
        self.tables_text.setPlainText("")
        self.graphics.clear()
        self.plots = {}
        self.status.setStyleSheet("")
        self.status.setText("Model selection appears here when the session finishes.")

    def run(self, session_path: str | Path) -> None:
        """Start the model selection of a finished session (worker thread)."""
        self._session_path = Path(session_path)
        if self.select_models is None:
            self.status.setText("Model selection is not available in this build.")
            return
        self.busy = True
        self.status.setText(f"Selecting models for {session_path} ...")
        fn, relay = self.select_models, self._relay

        def work():
            try:
                relay.done.emit(fn(Path(session_path)), None)
            except Exception as exc:  # shown in the panel, never raised into Qt
                log.exception("model selection failed")
                relay.done.emit(None, f"model selection failed: {exc}")
        try:
            self._pool.submit(work)
        except RuntimeError:  # the window is closing: its worker pool is shut down
            self.busy = False
            log.info("model selection not started: the window is closing")

    def _on_done(self, view, error) -> None:
        self.busy = False
        release_freed_memory()  # the model selection's freed heap back to the system
        if error:
            self.error = error
            self.status.setText(error)
            self.status.setStyleSheet(f"color: {Colour.FAULT};")
            return
        self.show_view(view)
        if self._session_path is not None:
            try:
                self.saved = list(view.saved) + self.save_beside(self._session_path)
            except OSError as exc:
                self.error = f"could not save the results: {exc}"
                log.error(self.error)
        names = ", ".join(p.name for p in self.saved)
        n = len(view.problems)
        self.status.setText(
            (view.note + "  " if view.note else "")
            + (f"{n} problem(s), listed below (also in problems.txt).  " if n else "")
            + (f"Saved beside the session file: {names}" if names else ""))

    def show_view(self, view: SelectionView) -> None:
        """Fill the table and draw the figures."""
        self.view = view
        self.tables_text.setPlainText(view.tables_text)
        self.problems.setPlainText("\n".join(f"- {p}" for p in view.problems))
        self.problems.setVisible(bool(view.problems))
        self.table.setRowCount(len(view.parameters))
        self.graphics.clear()
        self.plots = {}
        for row, par in enumerate(view.parameters):
            aicc = {f.model: f.aicc for f in par.fits}
            sel = next((f for f in par.fits if f.model == par.selected), None)
            cells = [f"{par.name}" + (f" ({par.units})" if par.units else "")]
            cells += [f"{aicc[m]:.2f}" if m in aicc and math.isfinite(aicc[m]) else "-"
                      for m in ("linear", "quadratic", "exponential")]
            cells += [par.selected, (_curve_text(sel) if sel else "-")
                      + (f"  ({par.trend})" if par.trend else "")]
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if col in (1, 2, 3) and ("linear", "quadratic", "exponential")[col - 1] \
                        == par.selected:
                    f = item.font()
                    f.setBold(True)
                    item.setFont(f)
                self.table.setItem(row, col, item)
            p = self.graphics.addPlot(row=0, col=row,
                                      title=f"{par.figure + ': ' if par.figure else ''}"
                                            f"{par.name} vs sE")
            p.setLabel("bottom", "sE")
            p.setLabel("left", par.name + (f" ({par.units})" if par.units else ""))
            p.getAxis("left").enableAutoSIPrefix(False)
            p.showGrid(x=True, y=True, alpha=0.3)
            legend = p.addLegend(offset=(5, 5))
            p.plot(par.sE, par.values, pen=None, symbol="o", symbolSize=8,
                   symbolBrush="k", name="identified")
            if len(par.excluded_sE):
                p.plot(par.excluded_sE, par.excluded_values, pen=None, symbol="o",
                       symbolSize=8, symbolBrush=None, symbolPen=pg.mkPen("k"),
                       name="outlier (IQR)")
            if len(par.sE):
                grid = np.linspace(float(np.min(par.sE)), float(np.max(par.sE)), 100)
                for fit in par.fits:
                    try:
                        y = model_curve(fit.model, fit.coefficients, grid)
                    except (ValueError, IndexError):
                        continue
                    chosen = fit.model == par.selected
                    pen = pg.mkPen(MODEL_COLOURS.get(fit.model, "#888"),
                                   width=3 if chosen else 1,
                                   style=Qt.PenStyle.SolidLine if chosen
                                   else Qt.PenStyle.DashLine)
                    p.plot(grid, y, pen=pen, name=fit.model + (" *" if chosen else ""))
            legend.setLabelTextSize("8pt")
            self.plots[par.name] = p

    def save_beside(self, session_path: Path) -> list[Path]:
        """Write the table (CSV) and a PNG of this panel into ``<stem>-analysis/`` next to
        the session file (where the analysis writes its report)."""
        if self.view is None:
            return []
        out = session_path.with_name(session_path.stem + "-analysis")
        out.mkdir(parents=True, exist_ok=True)
        csv_path = out / "gui_model_selection.csv"
        with open(csv_path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["parameter", "units", "model", "AICc", "selected", "coefficients"])
            for par in self.view.parameters:
                for fit in par.fits:
                    w.writerow([par.name, par.units, fit.model, f"{fit.aicc:.6g}",
                                int(fit.model == par.selected),
                                " ".join(f"{c:.6g}" for c in fit.coefficients)])
        png_path = out / "gui_model_selection.png"
        if not self.grab().save(str(png_path), "PNG"):
            raise OSError(f"{png_path}: could not write the PNG")
        return [csv_path, png_path]

    def shutdown(self, wait: bool = False) -> None:
        self._pool.shutdown(wait=wait, cancel_futures=True)


def _curve_text(fit: ModelFit) -> str:
    c = fit.coefficients
    if fit.model == "linear" and len(c) >= 2:
        return f"{c[0]:.3g} + {c[1]:.3g} sE"
    if fit.model == "quadratic" and len(c) >= 3:
        return f"{c[0]:.3g} + {c[1]:.3g} sE + {c[2]:.3g} sE^2"
    if fit.model == "exponential" and len(c) >= 2:
        return f"{c[0]:.3g} exp({c[1]:.3g} sE)"
    return " ".join(f"{v:.3g}" for v in c)
