"""Figures of an identification run (matplotlib, Agg backend, PNG files).

* measured vs fitted force for every sE level of a session;
* the paper's Figures 4-6: a parameter (participant average) against sE with the points
  used, the IQR outliers removed and the three fitted curves (the selected one bold).

matplotlib is an optional dependency (``nmsid[plot]``); it is imported only here.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from analysis.report import MODEL_TITLES, PARAMETER_TITLES


def _pyplot():
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def plot_level_fits(session_result, path: str | Path) -> Path:
    """Measured (preprocessed) and fitted force of every level, one panel per sE."""
    plt = _pyplot()
    levels = session_result.levels
    cols = 3
    rows = max(1, math.ceil(len(levels) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.2 * rows), squeeze=False,
                             sharex=True)
    for ax in axes.flat[len(levels):]:
        ax.set_visible(False)
    for ax, lv in zip(axes.flat, levels):
        if lv.fit is None:
            ax.text(0.5, 0.5, f"sE = {lv.sE:.2f}: not identified", ha="center",
                    va="center", transform=ax.transAxes)
            continue
        f = lv.fit
        ax.plot(f.t_s, f.y_N, lw=0.8, color="0.3", label="measured")
        ax.plot(f.t_s, f.y_fit_N, lw=0.8, color="tab:red", label="fitted")
        ax.plot(f.t_s, f.residual_N, lw=0.6, color="tab:blue", label="residual")
        ax.set_title(f"sE = {lv.sE:.2f}: Kp {f.Kp:.3g} N, wn {f.wn_rad_s:.3g} rad/s, "
                     f"zeta {f.zeta:.3g}, fit {f.fit_pct:.1f} %", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=7, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("time after stimulation onset (s)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("force (N)", fontsize=8)
    fig.suptitle(f"{session_result.participant}: measured vs fitted force", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_parameter_curves(selection, parameter: str, path: str | Path,
                          label: str = "average") -> Path:
    """A parameter against sE with the three fitted curves (Figures 4-6 of the paper)."""
    plt = _pyplot()
    comp = selection.comparison(parameter, label)
    fig, ax = plt.subplots(figsize=(5.5, 4))
    if comp is not None:
        used = [(p.sE, p.value) for p in comp.points if p.used]
        removed = [(p.sE, p.value) for p in comp.points
                   if not p.used and math.isfinite(p.value)]
        if used:
            ax.plot(*zip(*used), "o", color="k", ms=4, label="points used")
        if removed:
            ax.plot(*zip(*removed), "x", color="tab:gray", ms=6, label="IQR outliers")
        x, _ = comp.used_points()
        if len(x):
            grid = np.linspace(x.min(), x.max(), 200)
            for m, f in comp.fits.items():
                if not f.selectable:
                    continue
                bold = m == comp.selected
                ax.plot(grid, f.predict(grid), lw=2.2 if bold else 1.0,
                        ls="-" if bold else "--",
                        label=f"{MODEL_TITLES[m]} (AICc {f.aicc:.3g})" + (" *" if bold else ""))
        if comp.trend is not None:
            ax.set_title(textwrap.fill(f"{label}: {comp.trend.text}", 70), fontsize=7)
    ax.set_xlabel("sE")
    ax.set_ylabel(PARAMETER_TITLES.get(parameter, parameter))
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
