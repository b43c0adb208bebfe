"""Fisher information of the fit, against an independent lsim computation."""

import numpy as np
import pytest
from scipy.signal import lsim

from nmsid.analysis.second_order import fisher_information
from nmsid.analysis.settings import IdentificationSettings


def _chirp(fs, T, f0=1.0, f1=10.0):
    t = np.arange(int(T * fs)) / fs
    k = f1 / f0
    u = 0.5 * np.sin(2 * np.pi * f0 * T / np.log(k) * (k ** (t / T) - 1))
    return t, u - u.mean()


def _reference_crb(t, u, kp, wn, z, sd):
    """Finite differences of lsim (first-order hold) + offset, ramp, initial state."""
    def resp(p):
        k, w, zz = p
        return lsim(([k * w * w], [1, 2 * zz * w, w * w]), u, t)[1]
    p0 = np.array([kp, wn, z])
    cols = []
    for j in range(3):
        h = 1e-6 * p0[j]
        hi, lo = p0.copy(), p0.copy()
        hi[j] += h
        lo[j] -= h
        cols.append((resp(hi) - resp(lo)) / (2 * h))
    A = np.array([[0, 1], [-wn * wn, -2 * z * wn]])
    sys0 = (A, np.zeros((2, 1)), np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    for x0 in ([1.0, 0.0], [0.0, 1.0]):
        cols.append(lsim(sys0, np.zeros_like(t), t, X0=x0)[1])
    cols += [np.ones_like(t), np.linspace(-1, 1, len(t))]
    J = np.column_stack(cols)
    return np.sqrt(np.diag(np.linalg.inv(J.T @ J / sd ** 2))[:3])


@pytest.mark.parametrize("kp, wn, z", [(14.0, 55.0, 0.22), (8.0, 30.0, 0.6), (3.0, 10.0, 1.1)])
@pytest.mark.parametrize("sd", [0.01, 0.05])
def test_bound_matches_an_independent_lsim_computation(kp, wn, z, sd):
    t, u = _chirp(400.0, 6.0)
    s = IdentificationSettings(input_hold="linear")
    info = fisher_information(u, kp, wn, z, 400.0, sd, s)
    got = np.sqrt(np.diag(np.linalg.inv(info)))
    ref = _reference_crb(t, u, kp, wn, z, sd)
    assert np.allclose(got, ref, rtol=2e-3)


def test_information_scales_with_noise_amplitude_and_length():
    t, u = _chirp(200.0, 8.0)
    base = fisher_information(u, 6.0, 25.0, 0.5, 200.0, 0.04)
    assert np.allclose(fisher_information(u, 6.0, 25.0, 0.5, 200.0, 0.02), 4 * base)
    assert np.allclose(fisher_information(0.5 * u, 6.0, 25.0, 0.5, 200.0, 0.04), 0.25 * base,
                       rtol=1e-9, atol=1e-12 * np.abs(base).max())
    # twice the same periodic-ish excitation: about twice the information
    u2 = np.concatenate([u, u])
    two = fisher_information(u2, 6.0, 25.0, 0.5, 200.0, 0.04)
    ratio = np.diag(two) / np.diag(base)
    assert np.all((ratio > 1.8) & (ratio < 2.3))


def test_information_is_symmetric_positive_definite_for_a_multisine():
    from nmsid.protocols.waveforms import multisine_frequencies_Hz, multisine_unit
    fs, T = 200.0, 4.0
    t = np.arange(int(T * fs)) / fs
    u = 0.5 * multisine_unit(t, multisine_frequencies_Hz(1.0, 10.0, T, 12), T)
    info = fisher_information(u - u.mean(), 5.0, 20.0, 0.7, fs, 0.03)
    assert np.allclose(info, info.T, rtol=1e-8, atol=0)
    assert np.all(np.linalg.eigvalsh(info) > 0)
