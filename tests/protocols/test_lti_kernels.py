"""The simulator's LTI helpers (public ``scipy.signal``): the hold discretisation against
closed forms, the filter continued from its history against the exact recursion, and the
simulator's filter across chunks and coefficient changes against plain scipy calls."""

import math

import numpy as np
import pytest
import scipy.signal as ss
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols import lti_kernels as k
from nmsid.sim_backends import filters


def _muscle_like(draw_or_rng):
    """(wn rad/s, zeta, tau s) over the ranges participants and effects use."""
    rng = draw_or_rng
    return rng.uniform(2.0, 60.0), rng.uniform(0.2, 1.5), rng.uniform(0.0, 0.08)


def test_zoh_of_a_first_order_lag_is_the_closed_form():
    # 1 / (tau s + 1) held for dt: y[k] = e^(-dt/tau) y[k-1] + (1 - e^(-dt/tau)) u[k-1]
    tau, dt = 0.03, 1e-3
    b, a = k.cont2discrete_zoh([1.0], [tau, 1.0], dt)
    p = math.exp(-dt / tau)
    np.testing.assert_allclose(a, [1.0, -p], rtol=1e-15)
    np.testing.assert_allclose(b[0], [0.0, 1.0 - p], atol=1e-16, rtol=1e-13)


def test_zoh_keeps_unit_dc_gain_of_the_second_order_model():
    for wn, zeta in [(5.0, 0.3), (30.0, 0.9), (120.0, 1.4)]:
        b, a = filters.second_order_zoh(wn, zeta, 2000.0)
        assert b.sum() / a.sum() == pytest.approx(1.0, rel=1e-10)


def test_zoh_refuses_a_non_positive_sample_time():
    with pytest.raises(ValueError, match="dt_s"):
        k.cont2discrete_zoh([1.0], [1.0, 1.0], 0.0)


def test_lfilter_history_first_order_closed_form():
    # y[n] = p y[n-1] + (1 - p) x[n-1], at rest at 2 (past input and output 2), then input
    # 0: y[0] = 2 p + 2 (1 - p) = 2, y[n] = 2 p^n (1000 samples: 15 blocks carried)
    p_ = 0.999
    n = np.arange(1000)
    y = k.lfilter_history([0.0, 1 - p_], [1.0, -p_], np.zeros(1000), x_past=[2.0],
                          y_past=[2.0])
    np.testing.assert_allclose(y, 2 * p_ ** n, rtol=1e-12)


def test_lfilter_history_refuses_bad_coefficients_and_shapes():
    with pytest.raises(ValueError, match="coefficient"):
        k.lfilter_history([1.0], [0.0, 1.0], np.ones(3))
    assert k.lfilter_history([1.0], [1.0, -0.5], np.zeros(0), y_past=[1.0]).shape == (0,)
    with pytest.raises(ValueError, match="1-D"):
        k.lfilter_history([1.0], [1.0, -0.5], np.ones((2, 3)))


def _long_double_reference(b, a, x, xp, yp):
    """The difference equation sample by sample in long double (the truth)."""
    b = np.asarray(b, np.longdouble) / np.longdouble(a[0])
    a = np.asarray(a, np.longdouble) / np.longdouble(a[0])
    M, N = len(b) - 1, len(a) - 1
    X = list(np.asarray(xp, np.longdouble)[::-1]) + list(np.asarray(x, np.longdouble))
    Y = list(np.asarray(yp, np.longdouble)[::-1])
    for i in range(len(x)):
        Y.append(sum(b[j] * X[M + i - j] for j in range(M + 1))
                 - sum(a[j] * Y[-j] for j in range(1, N + 1)))
    return np.array(Y[N:], dtype=float)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), n=st.integers(1, 400))
def test_lfilter_history_on_the_simulators_stiff_filters(seed, n):
    """Slow muscles at 2000 Hz with an activation lag: a 3rd-order cascade whose poles
    crowd near z = 1 (|1 - p| ~ 1e-3). Within 2e-9 of the output's size of the exact
    (long double) recursion: scipy's transposed direct form II loses at most a few
    hundred ulps of the output over these lengths."""
    rng = np.random.default_rng(seed)
    wn, zeta, tau = _muscle_like(rng)
    b, a = filters.dynamics_zoh(wn, zeta, tau, 2000.0)
    order = len(a) - 1
    x = rng.uniform(0.0, 1.0, n)
    xp, yp = rng.uniform(0, 1, order), rng.uniform(0, 1, order)
    got = k.lfilter_history(b, a, x, xp, yp)
    scale = max(1.0, float(np.max(np.abs(got))))
    np.testing.assert_allclose(got, _long_double_reference(b, a, x, xp, yp), rtol=0,
                               atol=2e-9 * scale)


class _ScipyFilter:
    """The simulator's StatefulFilter as it was on scipy.signal (the reference)."""

    def __init__(self, order):
        self.order, self.b, self.a, self.zi = order, None, None, None
        self.xh, self.yh = np.zeros(order), np.zeros(order)

    def set(self, b, a):
        self.b, self.a = b, a
        self.zi = ss.lfiltic(b, a, self.yh, self.xh)

    def __call__(self, x):
        y, self.zi = ss.lfilter(self.b, self.a, x, zi=self.zi)
        k_ = self.order
        if x.size >= k_:
            self.xh, self.yh = x[-1:-k_ - 1:-1].copy(), y[-1:-k_ - 1:-1].copy()
        else:
            self.xh = np.concatenate([x[::-1], self.xh])[:k_]
            self.yh = np.concatenate([y[::-1], self.yh])[:k_]
        return y


@pytest.mark.parametrize("tau_s", [0.0, 0.02])
def test_the_simulators_filter_equals_scipys_across_chunks_and_coefficient_changes(tau_s):
    """A trial-like sequence: chunks of random lengths (1 to 4000 samples), a new sE (new
    coefficients) every few chunks; the simulator's filter stays within rounding of
    plain scipy calls. Bound 1e-8 (outputs of order 1): the two discretisations take
    different routes to the same coefficients (agreeing to ~1e-13 relative), and a filter
    with poles at 1 - p amplifies a coefficient error by ~1/p**2 (~1e5 for wn = 5 rad/s at
    2000 Hz); scipy's Windows build, another compiler, gave 1.1e-9 at tau 0.02 s."""
    rng = np.random.default_rng(7)
    order = 3 if tau_s > 0 else 2
    mine, ref = filters.StatefulFilter(order), _ScipyFilter(order)
    worst = 0.0
    for step in range(40):
        if step % 5 == 0:
            wn, zeta = rng.uniform(5.0, 40.0), rng.uniform(0.3, 1.2)
            num = [wn ** 2]
            den = np.polymul([tau_s, 1.0], [1.0, 2 * zeta * wn, wn ** 2]) if tau_s \
                else [1.0, 2 * zeta * wn, wn ** 2]
            b_ref, a_ref, _ = ss.cont2discrete((num, den), 1 / 2000.0, method="zoh")
            b_ref = np.atleast_1d(np.squeeze(b_ref))
            mine.set_coefficients(*filters.dynamics_zoh(wn, zeta, tau_s, 2000.0))
            ref.set(b_ref, np.asarray(a_ref))
        x = rng.uniform(0.0, 1.0, int(rng.integers(1, 4000)))
        worst = max(worst, float(np.max(np.abs(mine(x) - ref(x)))))
    assert worst < 1e-8
