"""The analysis's filters against scipy.signal / scipy.ndimage and closed forms, on both
paths: scipy's compiled kernel (the one filter path, bit-identical to scipy) and the numpy
block scan it falls back to when the kernel cannot be loaded (forced here)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import scipy.ndimage as nd
import scipy.signal as ss

from nmsid.analysis import signal_kernels as k
from nmsid.protocols import lti_kernels


def test_the_kernel_path_is_scipys_lfilter_bit_for_bit():
    """With the kernel: scipy's own numbers, with states; sosfilt is scipy.signal.sosfilt
    (its compiled _sosfilt: each sample through all sections, not the sections filtered one
    by one by lfilter, which rounds differently)."""
    assert lti_kernels.kernel_available()
    rng = np.random.default_rng(21)
    b, a = random_stable(rng, 3)
    x = rng.standard_normal((3, 2500)).cumsum(axis=1)
    np.testing.assert_array_equal(k.lfilter(b, a, x), ss.lfilter(b, a, x))
    zi = rng.standard_normal((3, max(len(a), len(b)) - 1))
    for got, ref in zip(k.lfilter(b, a, x, zi=zi), ss.lfilter(b, a, x, zi=zi)):
        np.testing.assert_array_equal(got, ref)
    sos = ss.butter(5, 0.05, output="sos")
    np.testing.assert_array_equal(k.sosfilt(sos, x), ss.sosfilt(sos, x))


def random_stable(rng, order):
    """A random stable, possibly resonant, denominator and numerator of an order."""
    poles = []
    while len(poles) < order:
        if order - len(poles) >= 2 and rng.random() < 0.6:
            r, th = rng.uniform(0.3, 0.999), rng.uniform(0.001, np.pi)
            poles += [r * np.exp(1j * th), r * np.exp(-1j * th)]
        else:
            poles.append(rng.uniform(-0.999, 0.999))
    a = np.real(np.poly(poles)) * rng.uniform(0.5, 2.0)
    b = rng.standard_normal(rng.integers(1, order + 2))
    return b, a


@pytest.mark.parametrize("n_samples", [1, 2, 15, 16, 17, 100, 1974, 20011])
@pytest.mark.parametrize("order", [1, 2, 3, 5])
def test_lfilter_matches_scipy(n_samples, order, filter_path):
    rng = np.random.default_rng(n_samples * 10 + order)
    b, a = random_stable(rng, order)
    scale = 10.0 ** rng.uniform(-3, 3)
    x = scale * rng.standard_normal((3, n_samples))
    tol = 1e-9 * scale * max(1.0, np.abs(ss.lfilter(b, a, x, axis=1)).max() / scale)
    assert np.abs(k.lfilter(b, a, x, axis=1) - ss.lfilter(b, a, x, axis=1)).max() <= tol
    assert np.abs(k.lfilter(b, a, x[0]) - ss.lfilter(b, a, x[0])).max() <= tol
    # along axis 0, with initial states
    n = max(len(a), len(b)) - 1
    zi = rng.standard_normal((n, 3))
    y1, z1 = k.lfilter(b, a, x.T, axis=0, zi=zi)
    y2, z2 = ss.lfilter(b, a, x.T, axis=0, zi=zi)
    assert y1.shape == y2.shape and z1.shape == z2.shape
    assert np.abs(y1 - y2).max() <= tol + 1e-9 * np.abs(y2).max()
    assert np.abs(z1 - z2).max() <= tol + 1e-9 * np.abs(z2).max()


def test_first_order_step_closed_form(filter_path):
    # y[n] = a y[n-1] + (1 - a) x[n], unit step: y[n] = 1 - a^(n+1)
    a = 0.97
    y = k.lfilter([1 - a], [1.0, -a], np.ones(500))
    assert np.allclose(y, 1 - a ** np.arange(1, 501), rtol=0, atol=1e-13)


def test_resonator_impulse_closed_form(filter_path):
    # poles r e^{+-i th}: h[n] = r^n sin((n+1) th) / sin(th)
    r, th = 0.995, 0.07
    a = [1.0, -2 * r * np.cos(th), r * r]
    imp = np.zeros(3000)
    imp[0] = 1.0
    n = np.arange(3000)
    assert np.allclose(k.lfilter([1.0], a, imp), r ** n * np.sin((n + 1) * th) / np.sin(th),
                       rtol=0, atol=1e-11)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("cutoff_Hz,fs_Hz", [(5.0, 2000.0), (20.0, 2000.0), (300.0, 2000.0),
                                             (40.0, 100.0)])
def test_butter_response_matches_scipy(order, cutoff_Hz, fs_Hz):
    mine = k.butter(order, cutoff_Hz, fs=fs_Hz, output="sos")
    ref = ss.butter(order, cutoff_Hz, fs=fs_Hz, output="sos")
    _, h1 = ss.sosfreqz(mine, worN=256, fs=fs_Hz)
    _, h2 = ss.sosfreqz(ref, worN=256, fs=fs_Hz)
    assert np.abs(h1 - h2).max() < 1e-9
    _, hc = ss.sosfreqz(mine, worN=[cutoff_Hz], fs=fs_Hz)
    assert abs(abs(hc[0]) - 2 ** -0.5) < 1e-9          # -3 dB at the cut-off


@pytest.mark.parametrize("n_samples", [40, 999, 21000])
@pytest.mark.parametrize("order", [1, 2, 4, 7])
def test_sosfilt_and_filtfilt_match_scipy(n_samples, order, filter_path):
    rng = np.random.default_rng(order + n_samples)
    sos = ss.butter(order, rng.uniform(0.02, 0.6), output="sos")
    x = rng.standard_normal((2, n_samples)).cumsum(axis=1)
    zi = ss.sosfilt_zi(sos)
    assert np.allclose(k.sosfilt_zi(sos), zi, rtol=1e-10, atol=1e-12)
    zi2 = zi[:, None, :] * x[None, :, :1]
    y1, z1 = k.sosfilt(sos, x, zi=zi2)
    y2, z2 = ss.sosfilt(sos, x, zi=zi2)
    assert np.allclose(y1, y2, rtol=1e-9, atol=1e-9) and np.allclose(z1, z2, rtol=1e-9,
                                                                     atol=1e-9)
    assert np.allclose(k.sosfilt(sos, x[1]), ss.sosfilt(sos, x[1]), rtol=1e-9, atol=1e-9)
    for padlen in (None, 0, min(n_samples - 1, 300)):
        if padlen is None and n_samples <= 3 * (2 * len(sos) + 1):
            continue
        assert np.allclose(k.sosfiltfilt(sos, x, padlen=padlen),
                           ss.sosfiltfilt(sos, x, padlen=padlen), rtol=1e-9, atol=1e-9)
    assert np.allclose(k.sosfiltfilt(sos, x.T, axis=0, padlen=30),
                       ss.sosfiltfilt(sos, x.T, axis=0, padlen=30), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("window", [3, 4, 7, 21, 41])
@pytest.mark.parametrize("polyorder", [0, 1, 2, 3])
def test_savgol_coeffs_match_scipy(window, polyorder):
    if polyorder >= window:
        pytest.skip("not a valid pair")
    for deriv in range(polyorder + 1):
        assert np.allclose(k.savgol_coeffs(window, polyorder, deriv=deriv, delta=0.5),
                           ss.savgol_coeffs(window, polyorder, deriv=deriv, delta=0.5),
                           rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("m", [1, 2, 3, 4, 21, 40])
@pytest.mark.parametrize("n_samples", [1, 5, 300])
def test_convolve1d_matches_ndimage(m, n_samples):
    rng = np.random.default_rng(m * 1000 + n_samples)
    x = rng.standard_normal((2, 3, n_samples))
    w = rng.standard_normal(m)
    assert np.allclose(k.convolve1d(x, w, axis=-1, mode="constant"),
                       nd.convolve1d(x, w, axis=-1, mode="constant"), atol=1e-12)
    assert np.allclose(k.convolve1d(x, w, axis=1, mode="constant", cval=2.5),
                       nd.convolve1d(x, w, axis=1, mode="constant", cval=2.5), atol=1e-12)


def test_unsupported_designs_are_refused_with_a_reason(filter_path):
    with pytest.raises(ValueError, match="low-pass"):
        k.butter(4, 20.0, btype="high", fs=2000.0, output="sos")
    with pytest.raises(ValueError, match="Nyquist"):
        k.butter(4, 1500.0, fs=2000.0, output="sos")
    with pytest.raises(ValueError, match="padlen"):
        k.sosfiltfilt(ss.butter(2, 0.1, output="sos"), np.ones(10), padlen=10)
    with pytest.raises(ValueError, match="a\\[0\\]"):
        k.lfilter([1.0], [0.0, 1.0], np.ones(3))


def test_identification_path_does_not_import_scipy_signal():
    import subprocess
    import sys
    code = ("import sys, nmsid.analysis.run, nmsid.cli.identify_command; "
            "print(sorted(m for m in sys.modules if m.startswith(('scipy.signal', 'scipy.linalg', "
            "'scipy.ndimage', 'scipy.special', 'matplotlib'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


@pytest.mark.parametrize("n,scale,seed", [(1, 0.01, 0), (3, 0.1, 1), (4, 1.0, 2),
                                          (5, 7.0, 3), (2, 40.0, 4), (6, 0.0, 5)])
def test_expm_matches_scipy(n, scale, seed):
    from scipy.linalg import expm as scipy_expm
    from nmsid.analysis.signal_kernels import expm
    M = np.random.default_rng(seed).normal(0, scale, (n, n))
    want = scipy_expm(M)
    np.testing.assert_allclose(expm(M), want, rtol=1e-12, atol=1e-14 * np.abs(want).max())


def test_expm_closed_forms():
    from nmsid.analysis.signal_kernels import expm
    t = 0.3
    np.testing.assert_allclose(expm([[0.0, t], [-t, 0.0]]),
                               [[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]], rtol=1e-14)
    np.testing.assert_allclose(expm([[-2.0, 1.0], [0.0, -2.0]]),
                               np.exp(-2.0) * np.array([[1.0, 1.0], [0.0, 1.0]]), rtol=1e-14)
    with pytest.raises(ValueError, match="square"):
        expm(np.ones((2, 3)))


@pytest.mark.parametrize("count", [1, 2, 3, 5, 16, 17, 33])
def test_block_powers_by_doubling_equal_repeated_products(count):
    A = np.random.default_rng(count).standard_normal((4, 4)) * 0.5
    P = k._powers(A, count)
    assert P.shape == (count, 4, 4)
    for i in range(count):
        assert np.allclose(P[i], np.linalg.matrix_power(A, i), rtol=1e-12, atol=1e-14)


def test_a_cascade_runs_as_one_state_space_with_each_sections_states(filter_path):
    """sosfilt (the kernel's sections one by one, or the fallback's single pass over the
    cascade) gives each section's final states (zf) as filtering section by section does
    (the sections' states, stacked)."""
    sos = ss.butter(5, 0.2, output="sos")                 # 3 sections, one first-order
    x = np.random.default_rng(3).standard_normal(500)
    y, zf = k.sosfilt(sos, x, zi=np.zeros((3, 2)))
    z_each, u = [], x
    for sec in sos:
        u, z = ss.lfilter(sec[:3], sec[3:], u, zi=np.zeros(2))
        z_each.append(z)
    assert np.allclose(y, u, rtol=1e-10, atol=1e-12)
    assert np.allclose(zf, np.array(z_each), rtol=1e-10, atol=1e-12)


def test_the_fallback_loses_digits_near_z_1_where_the_kernel_does_not(monkeypatch):
    """Why the compiled kernel is the one path: a slow 3rd-order cascade at 2 kHz (poles
    |1 - p| ~ 1e-3) -- the kernel is scipy's to the bit; the numpy scan drifts (the 4 %
    found on the simulator's filters; at least 1e-6 relative here)."""
    p = np.array([0.999, 0.9985, 0.998])
    a = np.poly(p)
    b = np.array([np.prod(1 - p)])
    x = np.ones(30000)
    ref = ss.lfilter(b, a, x)
    np.testing.assert_array_equal(k.lfilter(b, a, x), ref)
    monkeypatch.setattr(lti_kernels, "_kernel", None)
    monkeypatch.setattr(lti_kernels, "source", "unavailable")
    assert np.max(np.abs(k.lfilter(b, a, x) - ref)) > 1e-6 * np.max(np.abs(ref))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), order=st.integers(1, 8),
       cutoff=st.floats(0.01, 0.9), n=st.integers(30, 2000), ndim=st.integers(1, 3),
       axis=st.integers(-3, 2), padlen=st.one_of(st.none(), st.integers(0, 29)))
def test_sosfiltfilt_is_scipys_bit_for_bit(seed, order, cutoff, n, ndim, axis, padlen):
    """With the compiled _sosfilt: scipy.signal.sosfiltfilt's numbers and shape exactly on
    the same sections, 1-3-D data along any axis, any padding (QC's and preprocessing's
    zero-phase filter)."""
    axis = axis % ndim - (ndim if axis < 0 else 0)
    rng = np.random.default_rng(seed)
    sos = ss.butter(order, cutoff, output="sos")
    shape = [2, 3, 4][:ndim]
    shape[axis] = n
    x = rng.standard_normal(shape).cumsum(axis=axis)
    if padlen is None and n <= 3 * (2 * len(sos) + 1):
        padlen = 0
    got = k.sosfiltfilt(sos, x, axis=axis, padlen=padlen)
    ref = ss.sosfiltfilt(sos, x, axis=axis, padlen=padlen)
    assert got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)
    assert lti_kernels.sos_source == "compiled kernel"


def test_sosfilt_without_its_kernel_runs_the_sections_one_by_one(monkeypatch):
    """Without scipy's _sosfilt (another scipy layout), with lfilter's kernel: the sections
    one after the other through lfilter (scipy's numbers to rounding), and so do sections
    with a0 != 1 (which _sosfilt cannot take) and a zi that only broadcasts."""
    rng = np.random.default_rng(8)
    sos = ss.butter(4, 0.1, output="sos")
    x = rng.standard_normal((3, 800)).cumsum(axis=1)
    scaled = sos.copy()
    scaled[0] *= 2.0                                   # a0 = 2: the same filter
    zi = ss.sosfilt_zi(sos)[:, None, :] * x[None, :, :1]
    np.testing.assert_allclose(k.sosfilt(scaled, x), ss.sosfilt(sos, x), rtol=1e-10,
                               atol=1e-10)
    y, zf = k.sosfilt(sos, x, zi=ss.sosfilt_zi(sos)[:, None, :] * x[None, :1, :1])
    y_ref, zf_ref = ss.sosfilt(sos, x, zi=np.broadcast_to(
        ss.sosfilt_zi(sos)[:, None, :] * x[None, :1, :1], (2, 3, 2)))
    np.testing.assert_allclose(y, y_ref, rtol=1e-10, atol=1e-10)
    monkeypatch.setattr(lti_kernels, "_sos_kernel", None)
    monkeypatch.setattr(lti_kernels, "sos_source", "unavailable")
    assert lti_kernels.kernel_available() and not lti_kernels.sos_kernel_available()
    np.testing.assert_allclose(k.sosfilt(sos, x), ss.sosfilt(sos, x), rtol=1e-10, atol=1e-10)
    for got, ref in zip(k.sosfilt(sos, x, zi=zi), ss.sosfilt(sos, x, zi=zi)):
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(k.sosfiltfilt(sos, x), ss.sosfiltfilt(sos, x), rtol=1e-10,
                               atol=1e-10)


# -- a large zero-phase filter splits its rows between threads ---------------------------
def test_filter_threads_counts_cores_rows_and_size(monkeypatch):
    monkeypatch.setattr(k.os, "cpu_count", lambda: 8)
    assert k.filter_threads(45, 30000) == k.MAX_FILTER_THREADS == 4
    assert k.filter_threads(3, 100_000) == 3          # at most one per row
    assert k.filter_threads(1, 10**6) == 1            # one row: nothing to split
    assert k.filter_threads(45, 4000) == 1            # 180 000 samples: below the threshold
    assert k.filter_threads(50, 4000) == 4            # 200 000: at it
    monkeypatch.setattr(k.os, "cpu_count", lambda: None)
    assert k.filter_threads(45, 30000) == 1           # unknown core count: one thread


@pytest.mark.parametrize("cores", [2, 3, 4])
def test_threaded_sosfiltfilt_is_scipys_bit_for_bit(monkeypatch, cores):
    import threading
    import time
    seen = []
    real = k._sosfiltfilt_block

    def spy(*args, **kwargs):
        seen.append(threading.current_thread().name)
        if seen[-1] == "nmsid-sosfiltfilt":
            time.sleep(0.05)          # a slow helper: the caller must wait for its share
        return real(*args, **kwargs)

    monkeypatch.setattr(k, "_sosfiltfilt_block", spy)
    monkeypatch.setattr(k.os, "cpu_count", lambda: cores)
    monkeypatch.setattr(k, "PARALLEL_MIN_SAMPLES", 1000)
    x = np.random.default_rng(cores).normal(size=(2, 40, 600))
    sos = k.butter(4, 20.0, fs=2000.0)
    y = k.sosfiltfilt(sos, x, axis=-1)
    assert np.array_equal(y, ss.sosfiltfilt(sos, x, axis=-1))
    assert len(seen) == cores and seen.count("nmsid-sosfiltfilt") == cores - 1
    z = k.sosfiltfilt(sos, x, axis=1)                 # rows along another axis
    assert np.array_equal(z, ss.sosfiltfilt(sos, x, axis=1))


def test_an_error_in_a_filter_thread_reaches_the_caller(monkeypatch):
    real = k._sosfiltfilt_block

    def fails_in_helpers(sos, rows, padlen, out=None):
        import threading
        if threading.current_thread().name == "nmsid-sosfiltfilt":
            raise MemoryError("no room for the padded rows")
        return real(sos, rows, padlen, out=out)

    monkeypatch.setattr(k, "_sosfiltfilt_block", fails_in_helpers)
    monkeypatch.setattr(k.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(k, "PARALLEL_MIN_SAMPLES", 1000)
    with pytest.raises(MemoryError, match="padded rows"):
        k.sosfiltfilt(k.butter(2, 20.0, fs=2000.0), np.ones((4, 500)))
