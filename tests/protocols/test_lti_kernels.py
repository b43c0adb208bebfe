"""The lowest layer's LTI kernels against scipy.signal / scipy.linalg on random inputs, and
the simulator's filters built on them against the scipy filters they replaced."""

import math
from pathlib import Path

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


@settings(max_examples=60, deadline=None)
@given(wn=st.floats(0.5, 200.0), zeta=st.floats(0.05, 3.0),
       tau=st.one_of(st.just(0.0), st.floats(1e-3, 0.5)),
       fs=st.sampled_from([100.0, 200.0, 1000.0, 2000.0, 10000.0]))
def test_zoh_discretisation_matches_scipy_cont2discrete(wn, zeta, tau, fs):
    num = [wn ** 2]
    den = [1.0, 2 * zeta * wn, wn ** 2] if tau == 0 else \
        np.polymul([tau, 1.0], [1.0, 2 * zeta * wn, wn ** 2])
    b_ref, a_ref, _ = ss.cont2discrete((num, den), 1.0 / fs, method="zoh")
    b, a = k.cont2discrete_zoh(num, den, 1.0 / fs)
    assert b.shape == np.shape(b_ref) and a.shape == np.shape(a_ref)
    # both take poly(eigvals(.)) of the discretised matrix, ill-conditioned near a double
    # pole (zeta ~ 1: the eigenvalues move by sqrt(eps) for an eps change of the matrix)
    # and amplified by expm's squarings when dt |pole| >> 1; b = poly(A - BC) - poly(A)
    # cancels, so b carries an absolute error of that size too. So two equally good expm
    # give coefficients that differ by up to ~2e-11 |a| at 100 Hz, 1e-12 |a| at 2000 Hz
    # (3000 random systems over these ranges); the filter outputs agree to 1e-9 (below).
    tol = 1e-10 * float(np.sum(np.abs(a_ref)))
    np.testing.assert_allclose(a, a_ref, rtol=0, atol=tol)
    np.testing.assert_allclose(b, b_ref, rtol=0, atol=tol)


def test_zoh_matches_scipy_closely_over_the_simulators_range():
    """The participants' ranges at the simulator's 2000 Hz: within 1e-12 of |a|."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        wn, zeta, tau = _muscle_like(rng)
        den = np.polymul([tau, 1.0], [1.0, 2 * zeta * wn, wn ** 2]) if tau else \
            [1.0, 2 * zeta * wn, wn ** 2]
        b_ref, a_ref, _ = ss.cont2discrete(([wn ** 2], den), 1 / 2000.0, method="zoh")
        b, a = k.cont2discrete_zoh([wn ** 2], den, 1 / 2000.0)
        tol = 1e-12 * float(np.sum(np.abs(a_ref)))
        np.testing.assert_allclose(a, a_ref, rtol=0, atol=tol)
        np.testing.assert_allclose(b, b_ref, rtol=0, atol=tol)


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


@pytest.mark.parametrize("shape", [(2, 3), (3,), (2, 2)])
def test_tf2ss_and_ss2tf_match_scipy(shape):
    rng = np.random.default_rng(sum(shape))
    den = np.concatenate([[1.0], rng.uniform(0.5, 3.0, shape[-1] - 1)])
    num = rng.standard_normal(shape[0] if len(shape) > 1 else shape[-1])
    for got, ref in zip(k.tf2ss(num, den), ss.tf2ss(num, den)):
        np.testing.assert_allclose(got, ref, rtol=1e-14, atol=1e-15)
    A, B, C, D = ss.tf2ss(num, den)
    for got, ref in zip(k.ss2tf(A, B, C, D), ss.ss2tf(A, B, C, D)):
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_improper_and_zero_systems_are_refused():
    with pytest.raises(ValueError, match="improper"):
        k.tf2ss([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="non-zero"):
        k.tf2ss([1.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="must be > 0"):
        k.cont2discrete_zoh([1.0], [1.0, 1.0], 0.0)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), order_b=st.integers(0, 3),
       order_a=st.integers(0, 3), n=st.integers(1, 300), n_x=st.integers(0, 4),
       n_y=st.integers(0, 4))
def test_lfilter_history_is_lfilter_started_by_lfiltic(seed, order_b, order_a, n, n_x, n_y):
    """Any stable filter (poles inside |z| < 0.95), any lengths (below, at and above a block),
    short or missing pasts: scipy's lfilter from lfiltic's states, to rounding."""
    rng = np.random.default_rng(seed)
    poles = rng.uniform(-0.95, 0.95, order_a)
    a = np.poly(poles) * rng.uniform(0.5, 2.0) if order_a else np.array([rng.uniform(0.5, 2)])
    b = rng.standard_normal(order_b + 1)
    x = rng.standard_normal(n)
    xp, yp = rng.standard_normal(n_x), rng.standard_normal(n_y)
    zi = ss.lfiltic(b, a, yp, xp)
    ref = ss.lfilter(b, a, x, zi=zi)[0] if zi.size else ss.lfilter(b, a, x)
    got = k.lfilter_history(b, a, x, xp, yp)
    assert got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)        # the kernel: scipy's numbers, bit for bit
    fallback = k._history_numpy(np.asarray(b, float), np.asarray(a, float), x, xp, yp)
    scale = max(1.0, float(np.max(np.abs(ref), initial=0.0)))
    np.testing.assert_allclose(fallback, ref, rtol=0, atol=1e-12 * scale)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), order_b=st.integers(0, 3),
       order_a=st.integers(0, 3), n=st.integers(1, 300), axis=st.sampled_from([0, 1, -1]),
       with_zi=st.booleans())
def test_lfilter_is_scipys_bit_for_bit(seed, order_b, order_a, n, axis, with_zi):
    """Any coefficients (a[0] != 1 too; FIR included), 2-D data along any axis, with or
    without initial states: scipy.signal.lfilter's numbers and shapes exactly."""
    rng = np.random.default_rng(seed)
    a = np.poly(rng.uniform(-0.95, 0.95, order_a)) * rng.uniform(0.5, 2.0)
    b = rng.standard_normal(order_b + 1)
    x = rng.standard_normal((3, n) if axis != 0 else (n, 3))
    nz = max(order_a, order_b)
    if with_zi and nz:
        zi_shape = list(x.shape)
        zi_shape[axis] = nz
        zi = rng.standard_normal(zi_shape)
        got, ref = k.lfilter(b, a, x, axis=axis, zi=zi), ss.lfilter(b, a, x, axis=axis, zi=zi)
        for g, r in zip(got, ref):
            assert g.shape == r.shape
            np.testing.assert_array_equal(g, r)
    else:
        got, ref = k.lfilter(b, a, x, axis=axis), ss.lfilter(b, a, x, axis=axis)
        assert got.shape == ref.shape
        np.testing.assert_array_equal(got, ref)
    assert k.source == "compiled kernel"


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), order_b=st.integers(0, 3),
       order_a=st.integers(0, 3), n_x=st.integers(0, 5), n_y=st.integers(0, 5))
def test_lfiltic_is_scipys(seed, order_b, order_a, n_x, n_y):
    rng = np.random.default_rng(seed)
    a = np.poly(rng.uniform(-0.95, 0.95, order_a)) * rng.uniform(0.5, 2.0)
    b = rng.standard_normal(order_b + 1)
    yp, xp = rng.standard_normal(n_y), rng.standard_normal(n_x)
    np.testing.assert_array_equal(k.lfiltic(b, a, yp, xp), ss.lfiltic(b, a, yp, xp))
    np.testing.assert_array_equal(k.lfiltic(b, a, yp), ss.lfiltic(b, a, yp))


def test_lfilter_refuses_bad_coefficients_and_states():
    with pytest.raises(ValueError, match="a\\[0\\]"):
        k.lfilter([1.0], [0.0, 1.0], np.ones(3))
    with pytest.raises(ValueError, match="1-D"):
        k.lfilter([[1.0]], [1.0, 0.5], np.ones(3))
    with pytest.raises(ValueError, match="non-empty"):
        k.lfilter([], [1.0, 0.5], np.ones(3))
    with pytest.raises(ValueError):
        k.lfilter([1.0, 0.2, 0.1], [1.0, 0.5], np.ones(3), zi=np.zeros(1))   # needs 2
    with pytest.raises(ValueError, match="zi"):
        k.lfilter([1.0, 0.2, 0.1], [1.0], np.ones(3), zi=np.zeros(1))


def test_without_the_kernel_lfilter_is_the_public_function(monkeypatch):
    monkeypatch.setattr(k, "_kernel", None)
    monkeypatch.setattr(k, "source", None)
    monkeypatch.setattr(k, "_load_kernel", lambda: None)
    b, a = [0.2, 0.1], [1.0, -0.7]
    x = np.linspace(0.0, 1.0, 50)
    np.testing.assert_array_equal(k.lfilter(b, a, x), ss.lfilter(b, a, x))
    assert k.source == "unavailable" and not k.kernel_available()


def test_the_kernel_is_loaded_without_importing_scipy_signal():
    import subprocess
    import sys
    code = ("import sys, numpy as np\n"
            "from nmsid.protocols import lti_kernels as k\n"
            "y = k.lfilter([0.5], [1.0, -0.5], np.ones(3))\n"
            "print(k.source, sorted(m for m in sys.modules if m.startswith('scipy.signal')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "compiled kernel []"


def test_lfilter_history_first_order_closed_form(filter_path):
    # y[n] = p y[n-1] + (1 - p) x[n-1], at rest at 2 (past input and output 2), then input
    # 0: y[0] = 2 p + 2 (1 - p) = 2, y[n] = 2 p^n (1000 samples: 15 blocks carried)
    p_ = 0.999
    n = np.arange(1000)
    y = k.lfilter_history([0.0, 1 - p_], [1.0, -p_], np.zeros(1000), x_past=[2.0],
                          y_past=[2.0])
    np.testing.assert_allclose(y, 2 * p_ ** n, rtol=1e-12)


def test_lfilter_history_refuses_bad_coefficients_and_shapes(filter_path):
    with pytest.raises(ValueError, match="a\\[0\\]"):
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
@given(seed=st.integers(0, 2 ** 31 - 1), n=st.integers(1, 1500))
def test_lfilter_history_on_the_simulators_stiff_filters(seed, n):
    """Slow muscles at 2000 Hz with an activation lag: a 3rd-order cascade whose poles
    crowd near z = 1 (|1 - p| ~ 1e-3). Within 2e-9 of the output's size of the exact
    (long double) recursion and of scipy's (a log-depth scan of the direct-form state
    misses by 4 % here; the carried past as raw outputs instead of differences by 2e-6)."""
    rng = np.random.default_rng(seed)
    wn, zeta, tau = _muscle_like(rng)
    b, a = filters.dynamics_zoh(wn, zeta, tau, 2000.0)
    order = len(a) - 1
    x = rng.uniform(0.0, 1.0, n)
    xp, yp = rng.uniform(0, 1, order), rng.uniform(0, 1, order)
    got = k.lfilter_history(b, a, x, xp, yp)
    ref = ss.lfilter(b, a, x, zi=ss.lfiltic(b, a, yp, xp))[0]
    np.testing.assert_array_equal(got, ref)
    fallback = k._history_numpy(b, a, x, xp, yp)
    scale = max(1.0, float(np.max(np.abs(ref))))
    np.testing.assert_allclose(fallback, ref, rtol=0, atol=2e-9 * scale)
    if n <= 400:
        for y in (got, fallback):
            np.testing.assert_allclose(y, _long_double_reference(b, a, x, xp, yp), rtol=0,
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
def test_the_simulators_filter_equals_scipys_across_chunks_and_coefficient_changes(tau_s, filter_path):
    """A trial-like sequence: chunks of random lengths (1 to 4000 samples), a new sE (new
    coefficients) every few chunks; the numpy path stays within rounding of scipy's."""
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
    assert worst < 1e-9


def _random_sos(rng, n_sections: int) -> np.ndarray:
    """Stable sections (a0 = 1): a real pair or a resonant pair each, random zeros."""
    sos = np.empty((n_sections, 6))
    for i in range(n_sections):
        if rng.random() < 0.5:
            r, th = rng.uniform(0.3, 0.999), rng.uniform(0.001, np.pi)
            a = [1.0, -2 * r * np.cos(th), r * r]
        else:
            a = np.poly(rng.uniform(-0.99, 0.99, 2))
        sos[i] = np.concatenate([rng.standard_normal(3), a])
    return sos


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), n_sections=st.integers(1, 4),
       n=st.integers(1, 300), ndim=st.integers(1, 3), axis=st.integers(-3, 2),
       with_zi=st.booleans())
def test_sosfilt_is_scipys_bit_for_bit(seed, n_sections, n, ndim, axis, with_zi):
    """Any stable sections, 1-3-D data along any axis, with or without initial states:
    scipy.signal.sosfilt's numbers and shapes exactly (the same compiled _sosfilt)."""
    axis = axis % ndim - (ndim if axis < 0 else 0)      # a valid axis, either sign
    rng = np.random.default_rng(seed)
    sos = _random_sos(rng, n_sections)
    shape = [2, 3, 4][:ndim]
    shape[axis] = n
    x = rng.standard_normal(shape).cumsum(axis=axis)
    if with_zi:
        zi_shape = [n_sections] + list(shape)
        zi_shape[(axis % ndim) + 1] = 2
        zi = rng.standard_normal(zi_shape)
        (y, zf), (y_ref, zf_ref) = k.sosfilt(sos, x, axis, zi), ss.sosfilt(sos, x, axis, zi)
        assert zf.shape == zf_ref.shape
        np.testing.assert_array_equal(zf, zf_ref)
        np.testing.assert_array_equal(zi, np.asarray(zi))   # the caller's zi not modified
    else:
        y, y_ref = k.sosfilt(sos, x, axis=axis), ss.sosfilt(sos, x, axis=axis)
    assert y.shape == y_ref.shape
    np.testing.assert_array_equal(y, y_ref)
    assert k.sos_source == "compiled kernel"


def test_sosfilt_leaves_its_inputs_alone():
    """The kernel filters in place: on copies, never on the caller's x or zi."""
    rng = np.random.default_rng(3)
    sos = _random_sos(rng, 2)
    x = rng.standard_normal((2, 50))
    zi = rng.standard_normal((2, 2, 2))
    x0, zi0 = x.copy(), zi.copy()
    k.sosfilt(sos, x, zi=zi)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(zi, zi0)


def test_sosfilt_refuses_bad_sections_and_states():
    with pytest.raises(ValueError, match="n_sections, 6"):
        k.sosfilt(np.ones((2, 5)), np.ones(10))
    with pytest.raises(ValueError, match="a0"):
        k.sosfilt([[1.0, 0.0, 0.0, 2.0, 0.5, 0.0]], np.ones(10))
    with pytest.raises(ValueError, match="zi has shape"):
        k.sosfilt([[1.0, 0.0, 0.0, 1.0, 0.5, 0.0]], np.ones((3, 10)), zi=np.zeros((1, 2)))


def test_without_the_sos_kernel_sosfilt_is_the_public_function(monkeypatch):
    monkeypatch.setattr(k, "_sos_kernel", None)
    monkeypatch.setattr(k, "sos_source", None)
    monkeypatch.setattr(k, "_load_sos_kernel", lambda: None)
    sos = _random_sos(np.random.default_rng(5), 2)
    x = np.linspace(0.0, 1.0, 50)
    np.testing.assert_array_equal(k.sosfilt(sos, x), ss.sosfilt(sos, x))
    assert k.sos_source == "unavailable" and not k.sos_kernel_available()


def test_the_sos_kernel_is_loaded_without_importing_scipy_signal():
    import subprocess
    import sys
    code = ("import sys, numpy as np\n"
            "from nmsid.protocols import lti_kernels as k\n"
            "y = k.sosfilt([[0.5, 0, 0, 1, -0.5, 0]], np.ones(3))\n"
            "print(k.sos_source, sorted(m for m in sys.modules if m.startswith('scipy.signal')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "compiled kernel []"


@pytest.mark.parametrize("stem, function", [("_sosfilt", "_sosfilt"),
                                            ("_sigtools", "_linear_filter")])
def test_the_kernels_load_under_windows_file_names(tmp_path, monkeypatch, stem, function):
    """On Windows the extensions are ``<stem>.cp311-win_amd64.pyd`` (importlib.machinery.
    EXTENSION_SUFFIXES there: ".cp311-win_amd64.pyd", ".pyd"). Emulated: this platform's
    extension file copied under a Windows name into a scipy folder, the suffix list set to
    Windows'; the loader must find it by that list and load it, whatever the suffix."""
    import importlib.machinery
    import shutil

    import scipy
    real = next(p for sfx in importlib.machinery.EXTENSION_SUFFIXES
                if (p := Path(scipy.__file__).parent / "signal" / (stem + sfx)).is_file())
    (tmp_path / "signal").mkdir()
    shutil.copy(real, tmp_path / "signal" / f"{stem}.cp311-win_amd64.pyd")
    monkeypatch.setattr(scipy, "__file__", str(tmp_path / "__init__.py"))
    monkeypatch.setattr(importlib.machinery, "EXTENSION_SUFFIXES",
                        [".cp311-win_amd64.pyd", ".pyd"])
    fn = k._load_extension(stem, function)
    assert callable(fn) and fn.__name__ == function
    monkeypatch.setattr(importlib.machinery, "EXTENSION_SUFFIXES", [".so.none"])
    assert k._load_extension(stem, function) is None      # no file by these suffixes
