"""Figures of an identification run (matplotlib, :mod:`nmsid.analysis.plot_style`).

* ``fit_<participant>.png`` / ``.pdf``: per sE level, the measured force (a broad grey
  band) under the fitted response (a thin red line), and the residual in its own panel
  beneath;
* ``figure_<parameter>.png`` / ``.pdf``: the paper's Figures 4-6, a parameter against sE
  with the points used, the IQR outliers removed and the three fitted curves (the
  selected one bold): one participant's own values, or a group's average with each
  participant's values behind it.

Long traces are drawn as their min/max envelope over :data:`TRACE_COLUMNS` columns
(:func:`envelope`): every spike stays visible and the PDF stays small.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from nmsid.analysis import plot_style as style
from nmsid.analysis.model_selection import AVERAGE_LABEL
from nmsid.analysis.report import MODEL_TITLES, measured_title

#: columns of a trace's min/max envelope (about the panel's width in PNG pixels)
TRACE_COLUMNS = 600
_CURVE_COLOURS = {"linear": "tab:blue", "quadratic": "tab:orange",
                  "exponential": "tab:green"}


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


def _trace(ax, x, y, **kwargs) -> None:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() >= 2:
        ax.plot(*envelope(x[ok], y[ok], TRACE_COLUMNS), **kwargs)


def plot_level_fits(session_result, path: str | Path) -> Path:
    """Measured and fitted force with the residual beneath, one panel pair per sE.

    Returns
    -------
    Path
        The PNG (the PDF of the same name is written beside it).
    """
    plt = style.pyplot()
    levels = session_result.levels
    unit = getattr(session_result, "unit", "N")       # the joint's (docs/joints.md)
    measured = measured_title(session_result)          # "force (N)", "knee torque (N m)"
    cols = 3 if len(levels) > 4 else max(1, min(len(levels), 2))
    rows = max(1, math.ceil(len(levels) / cols))
    fig = plt.figure(figsize=(4.0 * cols, 2.9 * rows + 0.6))
    outer = fig.add_gridspec(rows, cols, hspace=0.55, wspace=0.28)
    c = style.COLOURS
    for i, lv in enumerate(levels):
        cell = outer[divmod(i, cols)].subgridspec(2, 1, height_ratios=[2.6, 1.0], hspace=0.08)
        ax = fig.add_subplot(cell[0])
        ax_r = fig.add_subplot(cell[1], sharex=ax)
        f = lv.fit
        if f is None:
            for a in (ax, ax_r):
                a.set_xticks([])
                a.set_yticks([])
            ax.text(0.5, 0.5, f"sE = {lv.sE:.2f}: not identified", ha="center",
                    va="center", transform=ax.transAxes)
            continue
        _trace(ax, f.t_s, f.y_N, color=c["reference"], lw=3.0, label="measured")
        _trace(ax, f.t_s, f.y_fit_N, color=c["fit"], lw=0.6, label="fitted")
        _trace(ax_r, f.t_s, f.residual_N, color=c["residual"], lw=0.6,
               label="residual (measured - fitted)")
        ax_r.axhline(0.0, color="k", lw=0.5)
        # plain Unicode symbols: mathtext's parser cost ~1 s over 15 panel titles
        ax.set_title(f"sE {lv.sE:.2f}: fit {f.fit_pct:.1f} %\n"
                     f"Kp {f.Kp:.3g} {unit}, \u03c9n {f.wn_rad_s:.3g} rad/s, "
                     f"\u03b6 {f.zeta:.3g}", fontsize=8.5)
        ax.tick_params(labelbottom=False)
        if i % cols == 0:
            ax.set_ylabel(measured)
            ax_r.set_ylabel(f"resid. ({unit})")
        if i >= len(levels) - cols:
            ax_r.set_xlabel("time after onset (s)")
    fig.suptitle(f"{style.group_title([session_result.participant], '')}: measured and "
                 f"fitted {measured.rsplit(' (', 1)[0]} per sE level", y=1.0)
    handles = [plt.Line2D([], [], color=c["reference"], lw=3.0, label="measured"),
               plt.Line2D([], [], color=c["fit"], lw=0.8, label="fitted"),
               plt.Line2D([], [], color=c["residual"], lw=0.8,
                          label="residual (measured - fitted), own panel")]
    fig.legend(handles=handles, loc="upper center", ncol=3, bbox_to_anchor=(0.5, 0.985))
    fig.subplots_adjust(top=1.0 - 0.95 / (2.9 * rows + 0.6), left=0.07, right=0.98,
                        bottom=0.5 / (2.9 * rows + 0.6))
    return style.save(fig, path, tight=False)[0]


def plot_parameter_curves(selection, parameter: str, path: str | Path,
                          label: str = AVERAGE_LABEL, unit: str = "N") -> Path:
    """A parameter against sE with the three fitted curves (Figures 4-6 of the paper); Kp
    in ``unit`` (the session joint's, docs/joints.md).

    With one participant the figure shows that participant's own comparison (the one its
    twin uses) and names the participant; with several, the comparison of ``label`` (the
    average) over every participant's used values.

    Returns
    -------
    Path
        The PNG (the PDF of the same name is written beside it).
    """
    plt = style.pyplot()
    people = list(selection.participants)
    if len(people) == 1:
        label = people[0]
    comp = selection.comparison(parameter, label)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    if len(people) > 1:
        for i, who in enumerate(people):
            other = selection.comparison(parameter, who)
            if other is None:
                continue
            x, y = other.used_points()
            ax.plot(x, y, ".", color="0.75", ms=4,
                    label="participants' values" if i == 0 else None, zorder=1)
    caption = ""
    if comp is None:
        ax.text(0.5, 0.5, f"no {parameter} comparison", ha="center", va="center",
                transform=ax.transAxes)
    else:
        x, _ = comp.used_points()
        if len(x):
            grid = np.linspace(x.min(), x.max(), 200)
            for m, fit in comp.fits.items():
                if not fit.selectable:
                    continue
                chosen = m == comp.selected
                aicc = "n/a" if fit.aicc is None else f"{fit.aicc:.4g}"
                ax.plot(grid, np.asarray(fit.predict(grid), float),
                        color=_CURVE_COLOURS.get(m, "0.4"), lw=2.6 if chosen else 1.0,
                        zorder=3 if chosen else 2,
                        label=f"{MODEL_TITLES.get(m, m)} (AICc {aicc})"
                              + (", selected" if chosen else ""))
        used = [(p.sE, p.value) for p in comp.points if p.used]
        removed = [(p.sE, p.value) for p in comp.points
                   if not p.used and math.isfinite(p.value)]
        if used:
            ax.plot(*zip(*used, strict=True), "o", color="k", ms=5, zorder=4, label="points used")
        if removed:
            ax.plot(*zip(*removed, strict=True), "x", color="0.5", ms=7, mew=1.5, zorder=4,
                    label="IQR outliers (not used)")
        if comp.trend is not None:
            caption = f"trend of the selected curve: {comp.trend.text}"
    ax.set_xlabel(r"stimulation level $s_E$ (-)")
    symbol = style.SYMBOLS.get(parameter, parameter)
    if parameter == "Kp":
        symbol = symbol.replace("(N)", f"({unit})")
    ax.set_ylabel(symbol)
    who = style.group_title(people, label)
    ax.set_title(f"{who}: {style.SYMBOLS.get(parameter, parameter).split(' (')[0]} "
                 "against sE")
    style.legend_outside(ax, "right")
    if caption:
        fig.text(0.01, -0.01, "\n".join(textwrap.wrap(caption, 110)[:3]), fontsize=7.5,
                 va="top", color="0.25", transform=fig.transFigure)
    return style.save(fig, path)[0]
