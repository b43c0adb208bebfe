"""Figures of an identification run (PNG files, drawn with Pillow).

* ``fit_<participant>.png``: measured vs fitted force and the residual, one small panel per
  sE level;
* ``figure_<parameter>.png``: the paper's Figures 4-6, a parameter (participant average)
  against sE with the points used, the IQR outliers removed and the three fitted curves
  (the selected one bold).

These are quick-look figures, drawn in a few milliseconds each: lines without
anti-aliasing, traces reduced to their per-pixel-column min/max envelope (so no spike or
noise band is hidden), plain ticks. matplotlib took 1.8 s of a 3 s ``nmsid identify``
(import, text layout, ``tight_layout``) for pictures whose numbers are all in
``parameters.csv`` and ``tables.txt``; Pillow, which comes with the ``plot`` extra, imports
in 20 ms. Pillow is imported only when a figure is drawn.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from nmsid.analysis.report import MODEL_TITLES, measured_title, parameter_titles

_WHITE = (255, 255, 255)
_BLACK = (0, 0, 0)
_GREY = (90, 90, 90)
_LIGHT = (150, 150, 150)
_RED = (214, 39, 40)
_BLUE = (31, 119, 180)
_CURVE_COLOURS = {"linear": (31, 119, 180), "quadratic": (255, 127, 14),
                  "exponential": (44, 160, 44)}


def _pil():
    # lazy: Pillow (the optional plot extra) is needed only when figures are drawn
    from PIL import Image, ImageDraw, ImageFont
    return Image, ImageDraw, ImageFont


def nice_ticks(lo: float, hi: float, max_ticks: int = 6) -> list[float]:
    """Round tick values (1, 2 or 5 times a power of ten apart) covering [lo, hi].

    Examples
    --------
    >>> nice_ticks(0.0, 1.0)
    [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
    >>> nice_ticks(-3.2, 7.9)
    [-2.0, 0.0, 2.0, 4.0, 6.0]
    """
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(1, max_ticks - 1)
    base = 10.0 ** math.floor(math.log10(raw))
    for step in (m * base for m in (0.5, 1, 2, 5, 10, 20)):
        first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
        if step >= raw / 2 and last - first + 1 <= max_ticks:
            break
    ticks = [round(k * step, 12) + 0.0 for k in range(first, last + 1)]
    return ticks


def _limits(*arrays) -> tuple[float, float]:
    vals = np.concatenate([np.ravel(np.asarray(a, float)) for a in arrays]) if arrays \
        else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return 0.0, 1.0
    lo, hi = float(vals.min()), float(vals.max())
    pad = 0.05 * (hi - lo) if hi > lo else max(abs(lo) * 0.1, 1e-3)
    return lo - pad, hi + pad


def envelope(x, y, n_columns: int) -> tuple[np.ndarray, np.ndarray]:
    """A trace reduced to ``n_columns`` min/max pairs (a polyline through both), or the
    trace itself when it is short enough. Keeps every extreme, so nothing is hidden.

    Examples
    --------
    >>> xs, ys = envelope(np.arange(1000.0), np.sin(np.arange(1000.0)), 50)
    >>> len(xs), float(ys.max()) == float(np.sin(np.arange(1000.0)).max())
    (100, True)
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    n = len(y)
    if n <= 2 * n_columns or n_columns < 1:
        return x, y
    per = n // n_columns
    m = per * n_columns
    yb = y[:m].reshape(n_columns, per)
    xb = x[:m].reshape(n_columns, per)
    lo_i, hi_i = np.argmin(yb, axis=1), np.argmax(yb, axis=1)
    rows = np.arange(n_columns)
    first = np.minimum(lo_i, hi_i)                  # keep the time order inside a column
    second = np.maximum(lo_i, hi_i)
    xs = np.stack([xb[rows, first], xb[rows, second]], axis=1).ravel()
    ys = np.stack([yb[rows, first], yb[rows, second]], axis=1).ravel()
    return xs, ys


class _Axes:
    """A rectangle of the image with data limits: frame, ticks, lines, markers, text."""

    def __init__(self, draw, font, box, xlim: tuple[float, float],
                 ylim: tuple[float, float]):
        self.draw, self.font = draw, font
        self.x0, self.y0, self.x1, self.y1 = box
        self.xlim, self.ylim = xlim, ylim

    def px(self, x, y):
        (a, b), (c, d) = self.xlim, self.ylim
        px = self.x0 + (np.asarray(x, float) - a) / (b - a) * (self.x1 - self.x0)
        py = self.y1 - (np.asarray(y, float) - c) / (d - c) * (self.y1 - self.y0)
        return np.clip(px, self.x0, self.x1), np.clip(py, self.y0, self.y1)

    def frame(self, xlabel: str = "", ylabel: str = "", title: str = "",
              x_ticklabels: bool = True):
        d, f = self.draw, self.font
        d.rectangle([self.x0, self.y0, self.x1, self.y1], outline=_BLACK)
        for t in nice_ticks(*self.xlim):
            x, _ = self.px(t, self.ylim[0])
            d.line([(x, self.y1), (x, self.y1 + 3)], fill=_BLACK)
            if x_ticklabels:
                d.text((x, self.y1 + 4), f"{t:g}", fill=_BLACK, font=f, anchor="ma")
        for t in nice_ticks(*self.ylim, max_ticks=5):
            _, y = self.px(self.xlim[0], t)
            d.line([(self.x0 - 3, y), (self.x0, y)], fill=_BLACK)
            d.text((self.x0 - 5, y), f"{t:g}", fill=_BLACK, font=f, anchor="rm")
        if xlabel:
            d.text(((self.x0 + self.x1) / 2, self.y1 + 17), xlabel, fill=_BLACK, font=f,
                   anchor="ma")
        if ylabel:
            d.text((self.x0 - 5, self.y0 - 4), ylabel, fill=_BLACK, font=f, anchor="rd")
        if title:
            d.text((self.x0, self.y0 - 3), title, fill=_BLACK, font=f, anchor="ld")

    def line(self, x, y, colour, width: int = 1):
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() < 2:
            return
        xs, ys = envelope(np.asarray(x)[ok], np.asarray(y)[ok], int(self.x1 - self.x0))
        px, py = self.px(xs, ys)
        self.draw.line(list(zip(px.tolist(), py.tolist())), fill=colour, width=width)

    def markers(self, x, y, colour, kind: str = "o", r: int = 3):
        px, py = self.px(x, y)
        for u, v in zip(px.tolist(), py.tolist()):
            if kind == "o":
                self.draw.ellipse([u - r, v - r, u + r, v + r], fill=colour)
            else:
                self.draw.line([(u - r, v - r), (u + r, v + r)], fill=colour, width=2)
                self.draw.line([(u - r, v + r), (u + r, v - r)], fill=colour, width=2)


def _legend(draw, font, x, y, entries):
    """Legend rows ``(label, colour, kind)`` from (x, y) downwards; kind line/o/x/bold."""
    for i, (label, colour, kind) in enumerate(entries):
        yy = y + 13 * i + 6
        if kind in ("line", "bold", "dashed"):
            draw.line([(x, yy), (x + 18, yy)], fill=colour, width=3 if kind == "bold" else 1)
        elif kind == "o":
            draw.ellipse([x + 6, yy - 3, x + 12, yy + 3], fill=colour)
        else:
            draw.line([(x + 6, yy - 3), (x + 12, yy + 3)], fill=colour, width=2)
            draw.line([(x + 6, yy + 3), (x + 12, yy - 3)], fill=colour, width=2)
        draw.text((x + 24, yy), label, fill=_BLACK, font=font, anchor="lm")


def _save(image, path) -> Path:
    image.save(path, format="PNG", compress_level=1)
    return Path(path)


def plot_level_fits(session_result, path: str | Path) -> Path:
    """Measured (preprocessed) and fitted force and the residual of every level, one
    panel per sE."""
    Image, ImageDraw, ImageFont = _pil()
    levels = session_result.levels
    cols = 3
    rows = max(1, math.ceil(len(levels) / cols))
    pw, ph = 310, 120                                # panel size in pixels
    left, top, gap_x, gap_y = 50, 62, 60, 48
    width = left + cols * pw + (cols - 1) * gap_x + 20
    height = top + rows * ph + (rows - 1) * gap_y + 40
    image = Image.new("RGB", (width, height), _WHITE)
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    unit = getattr(session_result, "unit", "N")
    draw.text((left, 8), f"{session_result.participant}: measured vs fitted "
                         f"{measured_title(session_result)} against time after stimulation "
                         "onset (s)", fill=_BLACK, font=font)
    for j, entry in enumerate([("measured", _GREY, "line"), ("fitted", _RED, "line"),
                               ("residual (measured - fitted)", _BLUE, "line")]):
        _legend(draw, font, left + 110 * j, 22, [entry])
    for i, lv in enumerate(levels):
        r, c = divmod(i, cols)
        x0 = left + c * (pw + gap_x)
        y0 = top + r * (ph + gap_y)
        box = (x0, y0, x0 + pw, y0 + ph)
        f = lv.fit
        if f is None:
            draw.rectangle(box, outline=_LIGHT)
            draw.text((x0 + pw / 2, y0 + ph / 2), f"sE = {lv.sE:.2f}: not identified",
                      fill=_BLACK, font=font, anchor="mm")
            continue
        ax = _Axes(draw, font, box, _limits(f.t_s), _limits(f.y_N, f.y_fit_N, f.residual_N))
        ax.frame(title=f"sE {lv.sE:.2f}: Kp {f.Kp:.3g} {unit}, wn {f.wn_rad_s:.3g} rad/s, "
                       f"zeta {f.zeta:.3g}, fit {f.fit_pct:.1f} %")
        ax.line(f.t_s, f.y_N, _GREY)
        ax.line(f.t_s, f.y_fit_N, _RED)
        ax.line(f.t_s, f.residual_N, _BLUE)
    return _save(image, path)


def plot_parameter_curves(selection, parameter: str, path: str | Path,
                          label: str = "average", unit: str = "N") -> Path:
    """A parameter against sE with the three fitted curves (Figures 4-6 of the paper); Kp
    in ``unit`` (the session joint's)."""
    Image, ImageDraw, ImageFont = _pil()
    width, height = 620, 440
    image = Image.new("RGB", (width, height), _WHITE)
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    comp = selection.comparison(parameter, label)
    box = (70, 56, width - 20, height - 150)
    used = removed = []
    curves = []
    if comp is not None:
        used = [(p.sE, p.value) for p in comp.points if p.used]
        removed = [(p.sE, p.value) for p in comp.points
                   if not p.used and math.isfinite(p.value)]
        x, _ = comp.used_points()
        if len(x):
            grid = np.linspace(x.min(), x.max(), 200)
            for m, fit in comp.fits.items():
                if fit.selectable:
                    curves.append((m, fit, grid, np.asarray(fit.predict(grid), float)))
    xs = [p[0] for p in used + removed] or [0.0, 1.0]
    ys = [p[1] for p in used + removed] + [v for *_, v in curves]
    ax = _Axes(draw, font, box, _limits(xs), _limits(*ys) if ys else (0.0, 1.0))
    ax.frame(xlabel="sE", ylabel=parameter_titles(unit).get(parameter, parameter))
    legend = []
    for m, fit, grid, values in curves:
        bold = m == comp.selected
        colour = _CURVE_COLOURS.get(m, _GREY)
        ax.line(grid, values, colour, width=3 if bold else 1)
        legend.append((f"{MODEL_TITLES.get(m, m)} (AICc {fit.aicc:.3g})"
                       + ("  * selected" if bold else ""), colour, "bold" if bold else "line"))
    if used:
        used_x, used_y = zip(*used)
        ax.markers(used_x, used_y, _BLACK, "o")
        legend.append(("points used", _BLACK, "o"))
    if removed:
        removed_x, removed_y = zip(*removed)
        ax.markers(removed_x, removed_y, _LIGHT, "x", r=4)
        legend.append(("IQR outliers", _LIGHT, "x"))
    if comp is not None and comp.trend is not None:
        for i, text in enumerate(textwrap.wrap(f"{label}: {comp.trend.text}", 95)[:3]):
            draw.text((10, 6 + 13 * i), text, fill=_BLACK, font=font)
    elif comp is None:
        draw.text((10, 6), f"{label}: no {parameter} comparison", fill=_BLACK, font=font)
    _legend(draw, font, box[0], box[3] + 40, legend)
    return _save(image, path)
