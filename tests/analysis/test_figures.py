"""The figures (issue 38, item 2): matplotlib through one style module, PNG at >= 150 dpi
beside a PDF, the measurement under the fit with the residual in its own panel, titles
naming the participant or the group, the verdict's model in the ranking, and no crash on
NaN or None values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from nmsid.analysis import plot_style as style
from nmsid.analysis.figures import envelope, plot_level_fits, plot_parameter_curves
from nmsid.analysis.gap import plots
from nmsid.analysis.muscle.report import plot_muscle


@pytest.fixture
def drawn(monkeypatch):
    """The figures handed to ``plot_style.save`` (saved as usual), to read their text."""
    figures = []
    real = style.save

    def keep(fig, path, **kwargs):
        figures.append({"texts": _texts(fig), "axes": fig.axes})
        return real(fig, path, **kwargs)

    monkeypatch.setattr(style, "save", keep)
    return figures


def _texts(fig) -> list[str]:
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.get_yticklabels() + ax.texts]
        leg = ax.get_legend()
        if leg is not None:
            out += [t.get_text() for t in leg.get_texts()]
    for leg in fig.legends:
        out += [t.get_text() for t in leg.get_texts()]
    if fig._suptitle is not None:
        out.append(fig._suptitle.get_text())
    return [t for t in out if t]


def _png_and_pdf(png) -> None:
    """A PNG at >= 150 dpi and the PDF of the same name beside it."""
    with Image.open(png) as img:
        dpi = img.info.get("dpi", (0, 0))
        assert min(dpi) >= 149.5, dpi                 # PNG pHYs, rounded by the format
        assert img.size[0] > 600
    assert png.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"


@pytest.mark.parametrize("n,cols", [(10, 50), (1000, 50), (30001, 310), (4096, 7)])
def test_envelope_keeps_every_extreme_and_the_time_order(n, cols):
    rng = np.random.default_rng(n)
    x = np.arange(n) / 2000.0
    y = rng.standard_normal(n).cumsum()
    y[n // 3] += 50.0                                  # a spike that must survive
    xs, ys = envelope(x, y, cols)
    assert len(xs) <= max(n, 2 * cols)
    assert np.all(np.diff(xs) >= 0)
    m = (n // cols) * cols if n > 2 * cols else n
    assert ys.max() == y[:m].max() and ys.min() == y[:m].min()
    assert set(ys.tolist()) <= set(y.tolist())


class _Fit:
    def __init__(self, rng, spike_at, nan=False):
        self.t_s = np.arange(20000) / 2000.0 + 5.0
        self.y_fit_N = np.sin(2 * np.pi * 3 * self.t_s)
        self.y_N = self.y_fit_N + 0.01 * rng.standard_normal(self.t_s.size)
        self.y_N[spike_at] += 3.0
        if nan:
            self.y_N[100:200] = np.nan                 # a gap in the measurement
        self.residual_N = self.y_N - self.y_fit_N
        self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = 2.0, 25.0, 0.6, 97.0


class _Level:
    def __init__(self, sE, fit):
        self.sE, self.fit = sE, fit


class _Session:
    def __init__(self, levels):
        self.participant, self.levels = "P01", levels


def test_level_fits_draw_measurement_fit_and_residual_panels(tmp_path, drawn):
    rng = np.random.default_rng(3)
    levels = [_Level(0.3 + 0.1 * i, _Fit(rng, 7000 + 1000 * i, nan=i == 1))
              for i in range(4)]
    levels.append(_Level(0.9, None))                   # not identified: said in its panel
    path = plot_level_fits(_Session(levels), tmp_path / "fit_P01.png")
    _png_and_pdf(path)
    (fig,) = drawn
    text = " ".join(fig["texts"])
    assert "participant P01" in text and "average" not in text
    assert "not identified" in text and "\u03c9n" in text and "rad/s" in text
    assert "residual" in text and "measured" in text and "fitted" in text
    # per identified level: the measured and fitted traces in one axes, the residual in
    # the axes beneath (its own panel), the one-sample spike kept by the envelope
    traces = [ax for ax in fig["axes"] if len(ax.lines) == 2
              and ax.lines[0].get_color() == style.COLOURS["reference"]
              and ax.lines[1].get_color() == style.COLOURS["fit"]]
    assert len(traces) == 4
    residual_axes = [ax for ax in fig["axes"] if len(ax.lines) == 2
                     and ax.lines[0].get_color() == style.COLOURS["residual"]]
    assert len(residual_axes) == 4
    assert max(float(np.nanmax(ax.lines[0].get_ydata())) for ax in residual_axes) > 2.9
    measured = traces[0].lines[0]
    assert measured.get_linewidth() > traces[0].lines[1].get_linewidth()  # visible under


class _Point:
    def __init__(self, sE, value, used=True):
        self.sE, self.value, self.used = sE, value, used


class _Curve:
    def __init__(self, slope, aicc):
        self.slope, self.aicc, self.selectable = slope, aicc, True

    def predict(self, x):
        return self.slope * np.asarray(x)


class _Comparison:
    def __init__(self, label, shift=0.0):
        self.label, self.selected = label, "linear"
        self.points = [_Point(s, 2 * s + shift) for s in (0.3, 0.5, 0.7, 0.9)] + \
            [_Point(1.0, 9.0, used=False), _Point(0.4, math.nan, used=False)]
        self.fits = {"linear": _Curve(2.0, -10.0), "quadratic": _Curve(2.1, None)}
        self.trend = type("T", (), {"text": "increasing"})()

    def used_points(self):
        pts = [(p.sE, p.value) for p in self.points if p.used]
        return np.array([p[0] for p in pts]), np.array([p[1] for p in pts])


class _Selection:
    def __init__(self, people):
        self.participants = people
        self._c = {lab: _Comparison(lab, 0.1 * i) for i, lab in enumerate(people)}
        self._c["average"] = _Comparison("average")

    def comparison(self, parameter, label):
        return self._c.get(label)


@pytest.mark.parametrize("people,title,not_in", [
    (["P07"], "participant P07", "average"),
    (["P01", "P02", "P03"], "average of 3 participants", "participant P0"),
])
def test_parameter_figure_names_the_participant_or_the_group(tmp_path, drawn, people,
                                                             title, not_in):
    path = plot_parameter_curves(_Selection(people), "wn_rad_s", tmp_path / "f.png")
    _png_and_pdf(path)
    text = " ".join(drawn[0]["texts"])
    assert title in text and not_in not in text
    assert r"$\omega_n$ (rad/s)" in text and "wn_rad_s" not in text
    assert "selected" in text and "IQR outliers" in text and "n/a" in text  # AICc None


def test_parameter_figure_without_a_comparison_says_so(tmp_path, drawn):
    sel = _Selection(["P01", "P02"])
    sel._c.clear()
    plot_parameter_curves(sel, "zeta", tmp_path / "f.png")
    assert "no zeta comparison" in " ".join(drawn[0]["texts"])


def _rank_row(effect, pct, supported):
    return {"effect": effect, "heldout_nrmse_pct": pct, "supported": supported}


def test_ranking_shows_the_muscle_twin_and_marks_the_winner(tmp_path, drawn):
    ranking = [_rank_row("dead_time", 3.0, True), _rank_row("fatigue", None, False),
               _rank_row("fatigue+dead_time", 2.5, True)]
    muscle = {"supported": True, "heldout": {"muscle_nrmse_pct": 1.2}}
    plots.plot_ranking(ranking, 10.0, 0.8, tmp_path / "ranking.png", muscle=muscle,
                       winner=plots.winner_label({"verdict": "muscle_twin"}))
    _png_and_pdf(tmp_path / "ranking.png")
    text = drawn[0]["texts"]
    assert "muscle twin  (verdict)" in text
    assert "dead time" in text and "fatigue + dead time" in text
    assert any("not converged" in t for t in text)       # the None row, named
    ax = drawn[0]["axes"][0]
    bars = [p for p in ax.patches if p.get_height() > 0 and p.get_width() > 0]
    winner = [p for p in bars if p.get_facecolor()[:3] == pytest.approx(
        (0.173, 0.627, 0.173), abs=0.01)]              # tab:green
    assert len(winner) == 1 and winner[0].get_width() == pytest.approx(1.2)


def test_muscle_figure_draws_none_and_nan_as_not_converged(tmp_path, drawn):
    rows = {"sE": [{"sE": 0.3, "nrmse_pct": 2.0}, {"sE": 0.6, "nrmse_pct": None}],
            "band": [{"f_lo_Hz": 1, "f_hi_Hz": 4, "nrmse_pct": float("nan")}],
            "abs_deviation": []}
    section = {"where": {"template": rows, "muscle": rows},
               "heldout": {"noise_floor_nrmse_pct": None, "template": "dead_time"}}
    plot_muscle(section, tmp_path / "muscle.png")
    _png_and_pdf(tmp_path / "muscle.png")
    assert sum("not converged" in t for t in drawn[0]["texts"]) == 4


def test_remaining_figure_takes_missing_thirds(tmp_path, drawn):
    report = {"verdict": "none", "best_effect": "none", "best_pair": None,
              "remaining": {"significant": False, "beyond_noise_pct_typical": None,
                            "where": {"sE": [{"sE": 0.3, "ratio_to_noise": 1.5}],
                                      "chirp_band": [{"f_lo_Hz": 1, "f_hi_Hz": 4,
                                                      "ratio_to_noise": None}],
                                      "trial_position": {"ratio_to_noise_by_third":
                                                         [1.0, None, float("nan")]}}}}
    plots.plot_remaining(report, tmp_path / "remaining.png")
    _png_and_pdf(tmp_path / "remaining.png")


def test_style_helpers():
    assert np.isnan(style.finite([None])[0])
    assert style.group_title(["A"], "average") == "participant A"
    assert style.effect_title("a_b+c") == "a b + c"
    assert style.DPI >= 150
