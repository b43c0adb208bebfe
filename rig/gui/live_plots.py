"""Live plots of the running trial: force, commanded rE, and the two currents.

The plots never receive data from the engine directly. A ``QTimer`` in the GUI thread
(at most ``max_fps`` per second, 30 by default) takes a snapshot of the
:class:`~rig.gui.live_buffer.LiveBuffer` and redraws only if the buffer changed; the
engine thread meanwhile only copies chunks into the buffer. pyqtgraph's clip-to-view and
peak downsampling keep each redraw cheap at 2 kHz.
"""

from __future__ import annotations

import pyqtgraph as pg
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from rig.gui.live_buffer import LiveBuffer, LiveSnapshot
from rig.gui.theme import Colour

MAX_FPS = 30.0


class LivePlots(QWidget):
    """Force, rE and currents of the current trial, redrawn from a timer.

    Parameters
    ----------
    buffer : LiveBuffer
        Filled by the engine observer.
    max_fps : float
        Upper bound of the redraw rate, frames per second (<= 30 by default).
    """

    def __init__(self, buffer: LiveBuffer, max_fps: float = MAX_FPS,
                 parent: QWidget | None = None):
        super().__init__(parent)
        if not 0 < max_fps <= 60:
            raise ValueError(f"live plot max_fps must be in (0, 60], got {max_fps!r}")
        self.buffer = buffer
        self.frames_drawn = 0
        self._last_generation = -1
        self.title = QLabel("No trial running")
        self.title.setStyleSheet("font-weight: bold; font-size: 14px;")
        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground("w")
        self.force_plot = self.graphics.addPlot(row=0, col=0)
        self.re_plot = self.graphics.addPlot(row=1, col=0)
        self.i_plot = self.graphics.addPlot(row=2, col=0)
        self.force_plot.setLabel("left", "force", units="N")
        self.re_plot.setLabel("left", "rE")
        self.i_plot.setLabel("left", "current", units="A")
        self.i_plot.setLabel("bottom", "time after onset", units="s")
        self.re_plot.setYRange(-0.05, 1.05)
        self.i_plot.addLegend(offset=(10, 5))
        for p in (self.force_plot, self.re_plot, self.i_plot):
            p.showGrid(x=True, y=True, alpha=0.3)
            p.setClipToView(True)
            p.setDownsampling(auto=True, mode="peak")
            p.setMouseEnabled(x=False, y=True)
        self.re_plot.setXLink(self.force_plot)
        self.i_plot.setXLink(self.force_plot)
        self.force_curve = self.force_plot.plot(pen=pg.mkPen(Colour.FORCE, width=1.5))
        self.re_curve = self.re_plot.plot(pen=pg.mkPen(Colour.RE, width=1.5))
        self.iext_curve = self.i_plot.plot(pen=pg.mkPen(Colour.I_EXT, width=1.5),
                                           name="I_ext")
        self.iflex_curve = self.i_plot.plot(pen=pg.mkPen(Colour.I_FLEX, width=1.5),
                                            name="I_flex")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.title)
        lay.addWidget(self.graphics, 1)
        self.timer = QTimer(self)
        self.timer.setInterval(max(1, int(round(1000.0 / max_fps))))
        self.timer.timeout.connect(self.redraw)
        self.timer.start()

    def set_title(self, text: str) -> None:
        self.title.setText(text)

    def redraw(self) -> None:
        """Draw the latest snapshot if the buffer changed since the last frame."""
        gen = self.buffer.generation
        if gen == self._last_generation:
            return
        snap = self.buffer.snapshot()
        self._last_generation = snap.generation
        self.draw(snap)

    def draw(self, snap: LiveSnapshot) -> None:
        t = snap.t_s
        self.force_curve.setData(t, snap.force_N)
        self.re_curve.setData(t, snap.rE)
        self.iext_curve.setData(t, snap.I_ext_mA * 1e-3)
        self.iflex_curve.setData(t, snap.I_flex_mA * 1e-3)
        if snap.n:
            window_s = self.buffer.capacity / self.buffer.fs_Hz
            t1 = max(float(t[-1]), window_s)
            self.force_plot.setXRange(t1 - window_s, t1, padding=0)
        self.frames_drawn += 1
