"""The exact triangle-hold discretisation and the smooth-input correction."""

import numpy as np
import pytest
from scipy.signal import cont2discrete, lfilter

from nmsid.analysis.discretize import foh_coefficients, foh_state_matrices, smooth_hold_input

CASES = [(8.0, 0.2, 5e-4), (30.0, 0.7, 5e-3), (60.0, 1.0, 5e-3), (45.0, 1.2, 5e-4),
         (500.0, 0.1, 5e-3), (20.0, 1.0 + 1e-9, 1e-3), (3000.0, 3.0, 5e-3)]


@pytest.mark.parametrize("wn,zeta,dt", CASES)
def test_matches_scipy_foh(wn, zeta, dt):
    num, den = foh_coefficients(wn, zeta, dt)
    b, a, _ = cont2discrete(([wn * wn], [1.0, 2 * zeta * wn, wn * wn]), dt, method="foh")
    assert den == pytest.approx(a, rel=1e-10, abs=1e-13)
    assert num == pytest.approx(np.ravel(b), rel=1e-8, abs=1e-15)
    assert num.sum() / den.sum() == pytest.approx(1.0, rel=1e-9)   # unit static gain


@pytest.mark.parametrize("wn,zeta,dt", CASES)
def test_state_matrices_agree_with_transfer_function(wn, zeta, dt):
    phi, g0, g1 = foh_state_matrices(np.array([wn]), np.array([zeta]), dt)
    u = np.random.default_rng(0).standard_normal(60)
    u[0] = 0.0
    x = np.zeros(2)
    y = [0.0]
    for k in range(59):
        x = phi[0] @ x + g0[0] * u[k] + g1[0] * u[k + 1]
        y.append(x[0])
    num, den = foh_coefficients(wn, zeta, dt)
    scale = max(1.0, np.max(np.abs(y)))
    assert np.max(np.abs(np.array(y) - lfilter(num, den, u))) < 1e-11 * scale


def test_critical_damping_is_continuous():
    a = foh_coefficients(30.0, 1.0, 1e-3)
    for z in (1 - 1e-7, 1 + 1e-7):
        b = foh_coefficients(30.0, z, 1e-3)
        assert np.allclose(a[0], b[0], rtol=1e-5) and np.allclose(a[1], b[1], rtol=1e-6)


def test_smooth_hold_cancels_triangle_attenuation():
    fs = 200.0
    t = np.arange(400) / fs
    for f in (1.0, 5.0, 10.0):
        u = np.sin(2 * np.pi * f * t)
        v = smooth_hold_input(u)
        gain = 1 / np.sinc(f / fs) ** 2           # 1/sinc^2 of the triangle hold
        err = np.max(np.abs(v[4:-4] - gain * u[4:-4]))
        assert err < 3e-6
    line = 2.0 + 0.1 * np.arange(50)
    assert np.allclose(smooth_hold_input(line), line)


@pytest.mark.parametrize("wn, zeta, dt", [(20.0, 0.4, 0.005), (3.0, 2.5, 0.0005),
                                          (0.5, 0.7, 0.001), (900.0, 0.05, 0.005)])
def test_coefficient_derivatives_are_central_differences_of_the_array_form(wn, zeta, dt):
    """The float path (and its cache) gives bit for bit what differencing the public
    array form gives; the cached arrays cannot be changed by a caller."""
    import math

    from nmsid.analysis import discretize as d
    lw, lz = math.log(wn), math.log(zeta)
    d._foh_derivatives.cache_clear()
    num, den, dnum, dden = d.foh_coefficients_with_derivatives(lw, lz, dt)
    n_ref, d_ref = foh_coefficients(math.exp(lw), math.exp(lz), dt)
    assert np.array_equal(num, n_ref) and np.array_equal(den, d_ref)
    for j, (p0, p1) in enumerate(((lw, lz), (lw, lz))):
        step = d._FD_STEP * max(1.0, abs((p0, p1)[j]))
        hi, lo = [p0, p1], [p0, p1]
        hi[j] += step
        lo[j] -= step
        n_hi, d_hi = foh_coefficients(math.exp(hi[0]), math.exp(hi[1]), dt)
        n_lo, d_lo = foh_coefficients(math.exp(lo[0]), math.exp(lo[1]), dt)
        assert np.array_equal(dnum[j], (n_hi - n_lo) / (2 * step))
        assert np.array_equal(dden[j], (d_hi - d_lo) / (2 * step))
    again = d.foh_coefficients_with_derivatives(lw, lz, dt)
    assert all(a is b for a, b in zip(again, (num, den, dnum, dden), strict=True))
    with pytest.raises(ValueError):
        num[0] = 0.0
