"""Running identification: Kp, wn, zeta and fit % against sE, growing level by level.

When the engine completes an sE level, :class:`IdentificationPanel` hands the level's
trials to a one-thread worker pool (never the GUI thread, never the engine thread); the
result comes back through a queued signal and is added to the four parameter-vs-sE plots.
A fit below ``bad_fit_pct`` is drawn in red and reported, so that the operator can re-run
that level while the participant is still there.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from nmsid.rig.gui.theme import LEFT_AXIS_PX, Colour

log = logging.getLogger(__name__)

#: (attribute of LevelPoint, axis label, units)
PARAMETERS = (("Kp", "Kp", "N"), ("wn_rad_s", "wn", "rad/s"), ("zeta", "zeta", ""),
              ("fit_pct", "fit", "%"))
BAD_FIT_PCT = 70.0


@dataclass(frozen=True)
class LevelPoint:
    """One sE level's identified parameters, as drawn."""

    sE: float
    Kp: float
    wn_rad_s: float
    zeta: float
    fit_pct: float
    n_trials: int = 0


def _first(obj, names, default=float("nan")) -> float:
    for name in names:
        if isinstance(obj, dict) and name in obj:
            return float(obj[name])
        if hasattr(obj, name):
            return float(getattr(obj, name))
    return default


def level_point(sE: float, result, n_trials: int = 0) -> LevelPoint:
    """Read the parameters out of an identification result object (or dict)."""
    return LevelPoint(
        sE=float(sE),
        Kp=_first(result, ("Kp", "Kp_N", "gain")),
        wn_rad_s=_first(result, ("wn_rad_s", "wn", "omega_n")),
        zeta=_first(result, ("zeta", "damping")),
        fit_pct=_first(result, ("fit_pct", "fit_percent", "fit")),
        n_trials=n_trials)


class _Relay(QObject):
    done = Signal(object, object)   # LevelPoint or None, error text or None


class IdentificationPanel(QWidget):
    """Four plots (Kp, wn, zeta, fit %) against sE, fed by a background identification.

    Parameters
    ----------
    identify : callable
        ``identify(trials) -> result`` with attributes Kp, wn_rad_s (or wn), zeta,
        fit_pct; runs in a worker thread.
    bad_fit_pct : float
        Fits below this are marked in red.
    """

    def __init__(self, identify: Callable | None = None, bad_fit_pct: float = BAD_FIT_PCT,
                 parent: QWidget | None = None):
        super().__init__(parent)
        self.identify = identify
        self.bad_fit_pct = bad_fit_pct
        self.points: list[LevelPoint] = []
        self.errors: list[str] = []
        self.pending = 0
        self.unit = "N"
        """The gain's unit (the session's joint's measured unit)."""
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="nmsid-identify")
        self.executor = self._pool
        """The panel's one analysis thread (the trial QC runs its jobs there too)."""
        self._relay = _Relay()
        self._relay.done.connect(self._on_done, Qt.ConnectionType.QueuedConnection)
        self.status = QLabel("Parameters appear here as each sE level completes.")
        self.status.setWordWrap(True)
        # two lines, fixed: a longer message never re-lays out the plots beside it
        self.status.setFixedHeight(2 * self.status.fontMetrics().lineSpacing() + 4)
        self.status.setStyleSheet("font-weight: bold;")
        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground("w")
        self.plots = {}
        self.scatter = {}
        self.bad_scatter = {}
        for k, (attr, label, units) in enumerate(PARAMETERS):
            p = self.graphics.addPlot(row=0, col=k)
            p.setLabel("left", f"{label}" + (f" ({units})" if units else ""))
            p.getAxis("left").enableAutoSIPrefix(False)
            p.getAxis("left").setWidth(LEFT_AXIS_PX)  # a new tick label: no re-layout
            p.setLabel("bottom", "sE")
            p.showGrid(x=True, y=True, alpha=0.3)
            p.setXRange(0.25, 1.05)
            self.plots[attr] = p
            self.scatter[attr] = p.plot([], [], pen=pg.mkPen(Colour.FORCE, width=1),
                                        symbol="o", symbolSize=9, symbolBrush=Colour.FORCE)
            self.bad_scatter[attr] = p.plot([], [], pen=None, symbol="x", symbolSize=14,
                                            symbolPen=pg.mkPen(Colour.FAULT, width=2),
                                            symbolBrush=Colour.FAULT)
        self.plots["fit_pct"].addItem(pg.InfiniteLine(
            pos=bad_fit_pct, angle=0, pen=pg.mkPen(Colour.FAULT, style=Qt.PenStyle.DashLine)))
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.status)
        lay.addWidget(self.graphics, 1)

    def set_joint(self, joint) -> None:
        """The gain's unit is the joint's measured unit (N, N m)."""
        self.unit = joint.unit
        self.plots["Kp"].setLabel("left", f"Kp ({joint.unit})")

    def reset(self) -> None:
        """Forget the previous session's points."""
        self.points = []
        self.errors = []
        for attr, _, _ in PARAMETERS:
            self.scatter[attr].setData([], [])
            self.bad_scatter[attr].setData([], [])
        self.status.setText("Parameters appear here as each sE level completes.")

    # -- feeding ----------------------------------------------------------------------
    def submit_level(self, sE: float, trials: list) -> Future | None:
        """Identify one completed level in the worker thread."""
        if self.identify is None:
            self.status.setText("Identification is not available in this build.")
            return None
        self.pending += 1
        self.status.setText(f"Identifying sE = {sE:.2f} ({len(trials)} trials) ...")
        identify, relay = self.identify, self._relay

        def work():
            try:
                point = level_point(sE, identify(trials), len(trials))
                relay.done.emit(point, None)
            except Exception as exc:  # reported in the panel and the log, never raised
                log.exception("identification of sE=%.2f failed", sE)
                relay.done.emit(None, f"sE = {sE:.2f}: identification failed: {exc}")
        try:
            return self._pool.submit(work)
        except RuntimeError:  # the window is closing: its worker pool is shut down
            self.pending -= 1
            log.info("identification of sE=%.2f not started: the window is closing", sE)
            return None

    def add_point(self, point: LevelPoint) -> None:
        """Add (or replace) one level's parameters and redraw."""
        self.points = [p for p in self.points if not math.isclose(p.sE, point.sE)]
        self.points.append(point)
        self.points.sort(key=lambda p: p.sE)
        sE = np.array([p.sE for p in self.points])
        bad = np.array([p.fit_pct < self.bad_fit_pct or not np.isfinite(p.fit_pct)
                        for p in self.points])
        for attr, _, _ in PARAMETERS:
            y = np.array([getattr(p, attr) for p in self.points])
            self.scatter[attr].setData(sE, y)
            self.bad_scatter[attr].setData(sE[bad], y[bad])
        msg = (f"sE = {point.sE:.2f}: Kp = {point.Kp:.3g} {self.unit}, "
               f"wn = {point.wn_rad_s:.3g} rad/s, zeta = {point.zeta:.3g}, "
               f"fit = {point.fit_pct:.1f} %")
        if point.fit_pct < self.bad_fit_pct:
            msg += f"  -- POOR FIT (< {self.bad_fit_pct:g} %): consider re-running this level"
        self.status.setText(msg)

    def _on_done(self, point, error) -> None:
        self.pending = max(0, self.pending - 1)
        if point is not None:
            self.add_point(point)
        if error:
            self.errors.append(error)
            self.status.setText(error)

    def shutdown(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
