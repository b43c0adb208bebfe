"""Live plots of the running trial: force, commanded rE, and the two currents.

The plots never receive data from the engine directly. A ``QTimer`` in the GUI thread
(at most ``max_fps`` per second, 30 by default) takes a snapshot of the
:class:`~nmsid.rig.gui.live_buffer.LiveBuffer` and redraws only if the buffer changed; the
engine thread meanwhile only copies chunks into the buffer. pyqtgraph's clip-to-view and
peak downsampling keep each redraw cheap at 2 kHz. Frames (and the samples between them)
are dropped when the engine runs faster than the window draws; nothing else is.

Units are fixed for the session: force in N, currents in mA (pyqtgraph's automatic SI
prefix is off, so an axis never flips between N and mN from one trial to the next).
The large readouts (:class:`Readouts`) show the latest commanded currents and force.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer
from PySide6.QtWidgets import QGridLayout, QLabel, QVBoxLayout, QWidget

from nmsid.protocols.joints import Joint
from nmsid.rig.gui.live_buffer import LiveBuffer, LiveSnapshot
from nmsid.rig.gui.theme import LEFT_AXIS_PX, Colour

log = logging.getLogger(__name__)

MAX_FPS = 30.0
#: Frames a late redraw may catch up on the absolute schedule.
MAX_LAG_FRAMES = 3
#: After a frame that took d seconds (its data and its paint), the next waits at least this
#: many times d: drawing takes at most a third of the GUI thread on a starved machine.
DRAW_SHARE_WAIT = 2.0


class TimedGraphicsLayout(pg.GraphicsLayoutWidget):
    """A ``GraphicsLayoutWidget`` that notes how long its last paint took (s): Qt paints
    after the frame's data were set, so the frame budget counts the paint too."""

    last_paint_s = 0.0
    paints = 0

    def paintEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        t0 = time.perf_counter()
        try:
            super().paintEvent(event)
        finally:
            self.last_paint_s = time.perf_counter() - t0
            self.paints += 1


class Readouts(QWidget):
    """Large numbers: the commanded extensor and flexor currents (mA) and the force (N).

    Fed by :class:`LivePlots` from each frame's latest sample, by the calibration steps,
    and set to 0 mA when the engine leaves stimulation (output off).
    """

    #: (key, label, unit, colour, format)
    FIELDS = (("I_ext", "extensor", "mA", Colour.I_EXT, "{:.1f}"),
              ("I_flex", "flexor", "mA", Colour.I_FLEX, "{:.1f}"),
              ("force", "force", "N", Colour.FORCE, "{:+.2f}"))

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        lay = QGridLayout(self)
        lay.setContentsMargins(6, 0, 6, 0)
        lay.setHorizontalSpacing(14)
        self.values: dict[str, QLabel] = {}
        self.names: dict[str, QLabel] = {}
        self.numbers: dict[str, float | None] = {}
        for col, (key, label, unit, colour, _) in enumerate(self.FIELDS):
            name = QLabel(f"{label} ({unit})")
            name.setStyleSheet("color: #555; font-size: 12px;")
            value = QLabel("-")
            value.setObjectName(f"readout_{key}")
            value.setMinimumWidth(110)
            value.setStyleSheet(f"color: {colour}; font-size: 30px; font-weight: bold;")
            lay.addWidget(name, 0, col)
            lay.addWidget(value, 1, col)
            self.values[key] = value
            self.names[key] = name
        self.reset()

    def set_joint(self, joint: Joint) -> None:
        """Name the channels by the joint's muscle groups and the measured quantity."""
        self.names["I_ext"].setText(f"{joint.extensor_muscles} (mA)")
        self.names["I_flex"].setText(f"{joint.flexor_muscles} (mA)")
        self.names["force"].setText(joint.quantity_label)

    def _set(self, key: str, number: float | None) -> None:
        self.numbers[key] = number
        fmt = next(f for k, _, _, _, f in self.FIELDS if k == key)
        self.values[key].setText("-" if number is None or not math.isfinite(number)
                                 else fmt.format(number))

    def set_values(self, I_ext_mA: float, I_flex_mA: float, force_N: float) -> None:
        """Show these numbers (mA, mA, N)."""
        self._set("I_ext", I_ext_mA)
        self._set("I_flex", I_flex_mA)
        self._set("force", force_N)

    def calibration_step(self, muscle: str, current_mA: float, force_N: float) -> None:
        """A ramp step: that muscle's current (the other at 0) and its force."""
        flex = str(muscle).lower().startswith("f")
        self.set_values(0.0 if flex else current_mA, current_mA if flex else 0.0, force_N)

    def output_on(self) -> None:
        """A trial stimulates: the frames' samples are shown."""
        self.live = True

    def output_off(self) -> None:
        """Stimulation stopped: both currents are 0 mA (the force keeps its last value);
        frames drawn late show no current until the next trial."""
        self.live = False
        self._set("I_ext", 0.0)
        self._set("I_flex", 0.0)

    def from_frame(self, I_ext_mA: float, I_flex_mA: float, force_N: float) -> None:
        """A frame's latest sample (ignored while the output is off)."""
        if self.live:
            self.set_values(I_ext_mA, I_flex_mA, force_N)

    def reset(self) -> None:
        self.live = False
        for key, *_ in self.FIELDS:
            self._set(key, None)


class LivePlots(QWidget):
    """Force, rE and currents of the current trial, redrawn from a timer.

    Parameters
    ----------
    buffer : LiveBuffer
        Filled by the engine observer.
    max_fps : float
        Upper bound of the redraw rate, frames per second (<= 30 by default).
    before_frame : callable, optional
        Called at each frame before the plots are drawn (the window shows the engine's
        pending notifications first: a frame never delays them).
    """

    def __init__(self, buffer: LiveBuffer, max_fps: float = MAX_FPS,
                 parent: QWidget | None = None,
                 before_frame: Callable[[], None] | None = None):
        super().__init__(parent)
        if not 0 < max_fps <= 60:
            raise ValueError(f"live plot max_fps must be in (0, 60], got {max_fps!r}")
        self.buffer = buffer
        self.before_frame = before_frame
        self.frames_drawn = 0
        self._last_generation = -1
        self.title = QLabel("No trial running")
        self.title.setStyleSheet("font-weight: bold; font-size: 14px;")
        self.graphics = TimedGraphicsLayout()
        self.graphics.setBackground("w")
        self.force_plot = self.graphics.addPlot(row=0, col=0)
        self.re_plot = self.graphics.addPlot(row=1, col=0)
        self.i_plot = self.graphics.addPlot(row=2, col=0)
        self.force_plot.setLabel("left", "force (N)")
        self.re_plot.setLabel("left", "rE")
        self.i_plot.setLabel("left", "current (mA)")
        self.i_plot.setLabel("bottom", "time after onset (s)")
        self.readouts = Readouts()
        self.re_plot.setYRange(-0.05, 1.05)
        self.i_plot.addLegend(offset=(10, 5))
        # one grid (the force's levels); grids are drawn by the axes, and each costs a
        # repaint of a whole plot's area whenever a range changes
        self.force_plot.showGrid(x=False, y=True, alpha=0.25)
        for p in (self.force_plot, self.re_plot, self.i_plot):
            p.getAxis("left").setWidth(LEFT_AXIS_PX)
            p.setClipToView(True)
            p.setDownsampling(auto=True, mode="peak")
            p.setMouseEnabled(x=False, y=False)
            p.enableAutoRange(x=False, y=False)
            p.hideButtons()
            for name in ("left", "bottom"):
                p.getAxis(name).enableAutoSIPrefix(False)  # one unit for the session
                # axes (with their grid) are redrawn only when their range changes
                p.getAxis(name).setCacheMode(
                    pg.QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)
        self._x0: float | None = None
        self._y_ranges: dict[int, tuple[float, float]] = {}
        self.re_plot.setXLink(self.force_plot)
        self.i_plot.setXLink(self.force_plot)
        self.force_curve = self.force_plot.plot(pen=pg.mkPen(Colour.FORCE, width=1))
        # a tracking trial's target force (dashed), empty during identification trials
        self.target_curve = self.force_plot.plot(
            pen=pg.mkPen(Colour.TARGET, width=2, style=Qt.PenStyle.DashLine),
            connect="finite")
        self.re_curve = self.re_plot.plot(pen=pg.mkPen(Colour.RE, width=1))
        self.iext_curve = self.i_plot.plot(pen=pg.mkPen(Colour.I_EXT, width=1),
                                           name="I_ext")
        self.iflex_curve = self.i_plot.plot(pen=pg.mkPen(Colour.I_FLEX, width=1),
                                            name="I_flex")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.title)
        lay.addWidget(self.graphics, 1)
        self.period_s = 1.0 / max_fps
        self._next_due = time.perf_counter()
        self.timer = QTimer(self)
        self.timer.setSingleShot(True)
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self._tick)
        self.timer.start(0)

    def _tick(self) -> None:
        """Frames on an absolute schedule (``period_s`` apart): never more than
        ``max_fps`` frames in any second (+1), and a frame delayed by a busy moment is made
        up (up to ``MAX_LAG_FRAMES``) instead of lost."""
        if self.before_frame is not None:
            try:
                self.before_frame()
            except Exception:  # a display problem must never stop the frames
                log.exception("before the live plots' frame")
        now = time.perf_counter()
        if now >= self._next_due:
            try:
                self.redraw()
            finally:
                self._next_due += self.period_s
                if self._next_due < now - MAX_LAG_FRAMES * self.period_s:
                    self._next_due = now  # after a long stall: do not burst
                # drawing (the data set now, and the last paint) takes at most a third of
                # the GUI thread's time: on a starved machine (a frame takes long) frames
                # are dropped so that the engine's notifications are still shown at once
                end = time.perf_counter()
                cost_s = end - now + self.graphics.last_paint_s
                self._next_due = max(self._next_due, end + DRAW_SHARE_WAIT * cost_s)
        delay_ms = max(0, math.ceil((self._next_due - time.perf_counter()) * 1000.0))
        self.timer.start(delay_ms)

    def set_joint(self, joint: Joint) -> None:
        """The session's joint: the measured quantity and its unit on the axis and the
        readouts (``torque (N m)`` for a knee), the muscle groups on the readouts."""
        self.force_plot.setLabel("left", joint.quantity_label)
        self.readouts.set_joint(joint)
        legend = self.i_plot.legend
        for curve, muscles in ((self.iext_curve, joint.extensor_muscles),
                               (self.iflex_curve, joint.flexor_muscles)):
            label = legend.getLabel(curve) if legend is not None else None
            if label is not None:
                label.setText(muscles)

    def set_title(self, text: str, duration_s: float | None = None) -> None:
        """Title of the trial shown; with ``duration_s`` the elapsed time is appended
        (updated every half second while samples arrive)."""
        self._title = text
        self._duration_s = duration_s
        self._shown_half_s: int | None = None
        self.title.setText(text)

    def _update_elapsed(self, t_last: float) -> None:
        if getattr(self, "_duration_s", None) is None:
            return
        half = int(t_last * 2)
        if half != self._shown_half_s:
            self._shown_half_s = half
            self.title.setText(f"{self._title}   {half / 2:.1f} / {self._duration_s:.1f} s")

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
        if snap.target_N is None:
            self.target_curve.setData([], [])
        else:
            self.target_curve.setData(t, snap.target_N)
        self.re_curve.setData(t, snap.rE)
        self.iext_curve.setData(t, snap.I_ext_mA)
        self.iflex_curve.setData(t, snap.I_flex_mA)
        if snap.n:
            self.readouts.from_frame(float(snap.I_ext_mA[-1]), float(snap.I_flex_mA[-1]),
                               float(snap.force_N[-1]))
            self._update_elapsed(float(t[-1]))
            self._follow_x(float(t[0]), float(t[-1]))
            self._fit_y(self.force_plot, snap.force_N if snap.target_N is None else
                        np.concatenate((snap.force_N,
                                        snap.target_N[np.isfinite(snap.target_N)])))
            self._fit_y(self.i_plot, np.concatenate((snap.I_ext_mA, snap.I_flex_mA)))
        self.frames_drawn += 1

    def _follow_x(self, t_first: float, t_last: float) -> None:
        """Scroll the time axis in pages of half a window, not every frame: each range
        change re-renders the axes, which costs more than drawing the curves."""
        window_s = self.buffer.capacity / self.buffer.fs_Hz
        page = window_s / 2
        x0 = self._x0
        if x0 is None or t_last > x0 + window_s or t_last < x0 or t_first < x0 - window_s:
            x0 = max(0.0, page * np.floor((t_last - window_s) / page + 1)) \
                if t_last > window_s else 0.0
            self._x0 = x0
            self.force_plot.setXRange(x0, x0 + window_s, padding=0)

    def _fit_y(self, plot, y: np.ndarray) -> None:
        """Grow the y range when the data leave it; shrink it only when the data use
        less than a third of it (few axis re-renders)."""
        finite = y[np.isfinite(y)]
        if not finite.size:
            return
        lo, hi = float(finite.min()), float(finite.max())
        span = max(hi - lo, 1e-3)
        cur = self._y_ranges.get(id(plot))
        if cur is None or lo < cur[0] or hi > cur[1] or span < (cur[1] - cur[0]) / 3:
            new = (lo - 0.15 * span, hi + 0.15 * span)
            self._y_ranges[id(plot)] = new
            plot.setYRange(*new, padding=0)

    def reset_view(self) -> None:
        """Start the next trial's plots at t = 0 with fresh ranges."""
        self._x0 = None
        self._y_ranges.clear()
