"""The quick-look figures: ticks, the min/max envelope, and PNGs that show the data."""

import math

import numpy as np
import pytest
from PIL import Image

from nmsid.analysis.figures import envelope, nice_ticks, plot_level_fits


@pytest.mark.parametrize("lo,hi", [(0.0, 1.0), (-3.2, 7.9), (1e-4, 3e-4), (250.0, 2600.0),
                                   (-1e6, -2.0), (0.30, 1.0)])
def test_nice_ticks_are_round_inside_and_enough(lo, hi):
    ticks = nice_ticks(lo, hi)
    assert 2 <= len(ticks) <= 6
    assert all(lo - 1e-12 * abs(hi - lo) <= t <= hi + 1e-12 * abs(hi - lo) for t in ticks)
    steps = np.diff(ticks)
    assert np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** math.floor(math.log10(steps[0]))
    assert any(abs(mantissa - m) < 1e-9 for m in (1, 2, 5, 10))


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
    def __init__(self, rng, spike_at):
        self.t_s = np.arange(20000) / 2000.0 + 5.0
        self.y_fit_N = np.sin(2 * np.pi * 3 * self.t_s)
        self.y_N = self.y_fit_N + 0.01 * rng.standard_normal(self.t_s.size)
        self.y_N[spike_at] += 3.0
        self.residual_N = self.y_N - self.y_fit_N
        self.Kp, self.wn_rad_s, self.zeta, self.fit_pct = 2.0, 25.0, 0.6, 97.0


class _Level:
    def __init__(self, sE, fit):
        self.sE, self.fit = sE, fit


class _Session:
    def __init__(self, levels):
        self.participant, self.levels = "P01", levels


def test_level_fits_png_shows_each_panel_and_a_one_sample_spike(tmp_path):
    rng = np.random.default_rng(3)
    levels = [_Level(0.3 + 0.1 * i, _Fit(rng, 7000 + 1000 * i)) for i in range(4)]
    levels.append(_Level(0.9, None))                   # not identified: said in its panel
    path = plot_level_fits(_Session(levels), tmp_path / "fit_P01.png")
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert img.shape[1] > 900 and img.shape[0] > 300
    blue = (np.abs(img - np.array([31, 119, 180])).sum(axis=2) < 10)
    red = (np.abs(img - np.array([214, 39, 40])).sum(axis=2) < 10)
    assert red.sum() > 1000 and blue.sum() > 500
    # each residual spike (3 N against a +-1 N sine) reaches far above the residual band:
    # the envelope keeps one-sample extremes, so the blue trace spans many pixel rows
    cols_with_blue = np.flatnonzero(blue.any(axis=0))
    heights = [np.ptp(np.flatnonzero(blue[:, c])) for c in cols_with_blue]
    assert max(heights) > 30
