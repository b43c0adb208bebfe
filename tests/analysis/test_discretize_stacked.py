"""The difference equations against scipy's first-order hold and closed forms."""

import numpy as np
import pytest
from scipy import signal

from nmsid.analysis.discretize import (
    fractional_delay,
    lagged_second_order_tf,
    parallel_tf,
    second_order_tf,
)


def _scipy_foh(num, den, dt):
    b, a, _ = signal.cont2discrete((num, den), dt, method="foh")
    return np.ravel(b), np.ravel(a)


@pytest.mark.parametrize("wn,zeta", [(30.0, 0.4), (12.0, 0.95), (50.0, 1.7), (20.0, 1.0)])
def test_second_order_matches_scipy_foh(wn, zeta):
    b, a = second_order_tf(np.array([wn]), np.array([zeta]), 0.002)
    b2, a2 = _scipy_foh([wn ** 2], [1, 2 * zeta * wn, wn ** 2], 0.002)
    np.testing.assert_allclose(a[0], a2, atol=1e-7)
    np.testing.assert_allclose(b[0], b2, atol=1e-7)


def test_lagged_second_order_matches_scipy_foh():
    wn, zeta, tau = 25.0, 0.6, 0.03
    den = np.polymul([tau, 1.0], [1, 2 * zeta * wn, wn ** 2])
    b, a = lagged_second_order_tf(np.array([wn]), np.array([zeta]), tau, 0.002)
    b2, a2 = _scipy_foh([wn ** 2], den, 0.002)
    np.testing.assert_allclose(a[0], a2 / a2[0], atol=1e-9)
    np.testing.assert_allclose(b[0], b2 / a2[0], atol=1e-9)


def test_unit_dc_gain_and_no_phase_error_at_10_Hz():
    """FOH at 500 Hz: gain within 0.2 % and phase within 0.01 deg of continuous time."""
    wn, zeta, dt = np.array([40.0]), np.array([0.5]), 0.002
    b, a = second_order_tf(wn, zeta, dt)
    assert b[0].sum() / a[0].sum() == pytest.approx(1.0, abs=1e-12)
    w = 2 * np.pi * 10
    z = np.exp(1j * w * dt)
    Hd = np.polyval(b[0], z) / np.polyval(a[0], z)
    Hc = wn[0] ** 2 / ((1j * w) ** 2 + 2 * zeta[0] * wn[0] * 1j * w + wn[0] ** 2)
    assert abs(Hd / Hc) == pytest.approx(1.0, abs=2e-3)
    assert abs(np.degrees(np.angle(Hd / Hc))) < 0.01


def test_parallel_is_the_mean_of_both_responses():
    u = np.random.default_rng(0).standard_normal(500)
    b1, a1 = second_order_tf(np.array([20.0]), np.array([0.5]), 0.002)
    b2, a2 = second_order_tf(np.array([45.0]), np.array([0.3]), 0.002)
    b, a = parallel_tf(b1, a1, b2, a2)
    y = signal.lfilter(b[0], a[0], u)
    ref = 0.5 * (signal.lfilter(b1[0], a1[0], u) + signal.lfilter(b2[0], a2[0], u))
    np.testing.assert_allclose(y, ref, atol=1e-9)


@pytest.mark.parametrize("delay_samples", [0.0, 0.37, 4.0, 12.81, -0.5, -0.37, -3.6])
def test_fractional_delay_of_a_slow_sine(delay_samples):
    """Either sign: a delay (the stimulation lags the record) or an advance."""
    fs = 500.0
    t = np.arange(3000) / fs
    x = np.sin(2 * np.pi * 7.0 * t + 0.3)[None, :]
    y = fractional_delay(x, delay_samples)
    ref = np.sin(2 * np.pi * 7.0 * (t - delay_samples / fs) + 0.3)
    np.testing.assert_allclose(y[0, 20:-20], ref[20:-20], atol=2e-5)
    if delay_samples >= 2:   # before the start the input rests at its first sample
        assert np.all(y[0, :int(delay_samples) - 1] == x[0, 0])
