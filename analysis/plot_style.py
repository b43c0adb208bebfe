"""The one style of every figure a command writes (matplotlib, headless).

Each figure module gets pyplot from :func:`pyplot` (the Agg backend, chosen explicitly:
no display is needed, none is opened) and writes through :func:`save`: a PNG at
:data:`DPI` dots per inch for the HTML reports and a vector PDF of the same figure beside
it, for a paper. Axis labels use :data:`SYMBOLS` (``ω_n`` in rad/s, ``ζ``, ``K_p`` in N),
legends sit outside the axes (:func:`legend_outside`) so they never cover data, and
:func:`finite` turns the ``None`` of a JSON report into NaN, which matplotlib leaves out
of a line and draws as an empty bar.

matplotlib is the ``plot`` extra: it is imported inside :func:`pyplot`, so a command run
without figures never loads it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DPI", "SYMBOLS", "COLOURS", "pyplot", "save", "legend_outside", "legend_above",
           "finite", "group_title", "mark_missing", "effect_title", "plain_log_ticks"]

#: dots per inch of every PNG (the PDF beside it is vector)
DPI = 160
#: axis labels of the model's parameters, with units (mathtext symbols)
SYMBOLS = {"Kp": r"$K_p$ (N)", "wn_rad_s": r"$\omega_n$ (rad/s)", "zeta": r"$\zeta$ (-)"}
#: the one palette: measurement, fit, residual, reference, the augmented / winning model
COLOURS = {"measured": "0.15", "fit": "#b2182b", "residual": "tab:blue",
           "reference": "0.62", "augmented": "tab:blue", "winner": "tab:green",
           "unsupported": "0.75", "noise": "k"}

_PAD_IN = 0.05                 # white margin around the tight box, inches
_RC: dict[str, Any] = {
    "font.size": 9.0, "axes.titlesize": 9.5, "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0, "ytick.labelsize": 8.0, "legend.fontsize": 8.0,
    "figure.titlesize": 10.5, "axes.spines.top": False, "axes.spines.right": False,
    "axes.grid": True, "grid.color": "0.9", "grid.linewidth": 0.6,
    "lines.linewidth": 1.0, "legend.frameon": False,
    "pdf.fonttype": 42,            # TrueType in the PDF: text stays text in an editor
    "mathtext.default": "regular",
}


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend with the house style applied.

    Raises
    ------
    ImportError
        When matplotlib (the ``plot`` extra) is not installed.
    """
    import matplotlib
    matplotlib.use("Agg")               # headless: files only, never a window
    import matplotlib.pyplot as plt
    plt.style.use(_RC)                  # a dict of rc settings (matplotlib.style.use)
    return plt


def save(fig, png_path: str | Path, *, tight: bool = True) -> list[Path]:
    """Write ``fig`` as ``png_path`` (:data:`DPI`) and as the PDF of the same name beside
    it, then close it.

    ``tight``: crop to everything drawn (legends placed outside the axes included); a
    figure laid out in full by its own ``subplots_adjust`` passes False and saves the
    page as it is (measuring every text of a 30-axes figure for the box cost ~1 s).

    Returns
    -------
    list of Path
        ``[png, pdf]``.
    """
    import matplotlib.pyplot as plt
    png = Path(png_path)
    pdf = png.with_suffix(".pdf")
    try:
        # the tight box once for both files (savefig's bbox_inches="tight" lays the figure
        # out again for each): legends placed outside the axes stay inside the image
        box = fig.get_tightbbox(fig.canvas.get_renderer()).padded(_PAD_IN) if tight \
            else None
        fig.savefig(png, dpi=DPI, bbox_inches=box)
        fig.savefig(pdf, bbox_inches=box)
    finally:
        plt.close(fig)
    return [png, pdf]


def legend_outside(ax, where: str = "right", **kwargs: Any):
    """A legend beside the axes (``"right"``) or under them (``"below"``), never on the
    data; nothing when the axes have no labelled artist."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    if where == "below":
        return ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.22),
                         ncol=kwargs.pop("ncol", min(3, len(handles))), **kwargs)
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                     **kwargs)


def legend_above(fig, *axes, ncol: int = 4):
    """One legend for the whole figure above its axes (call after ``tight_layout``): the
    labelled artists of ``axes``, each label once."""
    seen: dict[str, Any] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(lab, h)
    if not seen:
        return None
    return fig.legend(list(seen.values()), list(seen), loc="lower center",
                      bbox_to_anchor=(0.5, 1.0), ncol=min(ncol, len(seen)))


def plain_log_ticks(ax, axis: str = "x") -> None:
    """Tick labels of a logarithmic axis as plain numbers (2, 5, 10), not powers of ten."""
    from matplotlib.ticker import FuncFormatter, LogLocator
    fmt = FuncFormatter(lambda v, _pos: f"{v:g}")
    target = ax.xaxis if axis == "x" else ax.yaxis
    target.set_major_formatter(fmt)
    target.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
    target.set_minor_formatter(fmt)


def finite(values) -> np.ndarray:
    """Floats with ``None`` (a JSON report's "not computed") as NaN.

    Examples
    --------
    >>> finite([1, None, 2.5]).tolist()
    [1.0, nan, 2.5]
    """
    return np.array([math.nan if v is None else float(v) for v in values], dtype=float)


def mark_missing(ax, x, values, text: str = "not converged") -> None:
    """Write ``text`` at each position of ``x`` whose value is not finite (a bar that is
    not drawn says why)."""
    for xi, v in zip(x, values, strict=True):
        if not math.isfinite(v):
            ax.text(xi, 0.0, text, rotation=90, ha="center", va="bottom", fontsize=7,
                    color="0.35", transform=ax.get_xaxis_transform())


def effect_title(label: str) -> str:
    """An effect's or a pair's report name as words.

    Examples
    --------
    >>> effect_title("dead_time+fatigue")
    'dead time + fatigue'
    """
    return " + ".join(part.replace("_", " ") for part in label.split("+"))


def group_title(participants, label: str) -> str:
    """Who a figure shows: the participant's code for one participant, else the group's
    label and its size.

    Examples
    --------
    >>> group_title(["P01"], "average")
    'participant P01'
    >>> group_title(["P01", "P02"], "average")
    'average of 2 participants'
    """
    people = list(participants)
    if len(people) == 1:
        return f"participant {people[0]}"
    return f"{label} of {len(people)} participants"
