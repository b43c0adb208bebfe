"""Continuous-time linear models -> difference equations for ``scipy.signal.lfilter``.

The first-order hold (the input is taken as linear between samples) is exact for a
piecewise-linear input and, unlike a zero-order hold, adds no half-sample delay, which would
otherwise look like dead time. The models used in fitting (:func:`second_order_tf`,
:func:`lagged_second_order_tf`, :func:`parallel_tf`) are computed in closed form from their
poles, vectorised over sE levels (a matrix exponential per level would cost more than the
simulation itself); :func:`foh_tf` is the general state-space route, kept as the reference
the tests compare against.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg


def foh_tf(A: np.ndarray, B: np.ndarray, C: np.ndarray, dt_s: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """First-order-hold discretisation of a SISO state-space model.

    Parameters
    ----------
    A : (n, n) ndarray
    B : (n,) ndarray
    C : (n,) ndarray
        ``x' = A x + B u``, ``y = C x`` (no direct feed-through).
    dt_s : float
        Sample interval in s.

    Returns
    -------
    b, a : ndarray
        Numerator and denominator (length n + 1, ``a[0] = 1``) for ``lfilter``.

    Examples
    --------
    >>> import numpy as np
    >>> b, a = foh_tf(np.array([[-2.0]]), np.array([2.0]), np.array([1.0]), 0.01)
    >>> round(float(b.sum() / a.sum()), 12)   # unit DC gain
    1.0
    """
    n = A.shape[0]
    em = np.zeros((n + 2, n + 2))
    em[:n, :n] = A * dt_s
    em[:n, n] = B * dt_s
    em[n, n + 1] = 1.0
    ms = linalg.expm(em)
    ad = ms[:n, :n]
    m12 = ms[:n, n]
    m13 = ms[:n, n + 1]
    bd = m12 - m13 + ad @ m13
    dd = float(C @ m13)
    den = np.real(np.poly(ad))
    num = np.real(np.poly(ad - np.outer(bd, C))) - den + dd * den
    return num, den


def fractional_delay(x: np.ndarray, delay_samples: float) -> np.ndarray:
    """Delay each row by a (fractional) number of samples; zero before the start.

    Integer shift plus a 4-tap Lagrange interpolator (error below 1e-5 of the amplitude for
    content under 5 % of the sampling rate; at 250 Hz the 1-10 Hz chirp is under 4 %)."""
    n = x.shape[-1]
    k = int(np.floor(delay_samples))
    mu = delay_samples - k
    # taps for samples (k-1, k, k+1, k+2) behind: Lagrange at offset mu from sample k
    c = np.array([-mu * (mu - 1) * (mu - 2) / 6, (mu + 1) * (mu - 1) * (mu - 2) / 2,
                  -(mu + 1) * mu * (mu - 2) / 2, (mu + 1) * mu * (mu - 1) / 6])
    pad = np.zeros(x.shape[:-1] + (k + 3,))
    xp = np.concatenate([pad, x, np.zeros(x.shape[:-1] + (1,))], axis=-1)
    out = np.zeros_like(x)
    for tap, shift in zip(c, (k - 1, k, k + 1, k + 2)):
        start = k + 3 - shift
        out += tap * xp[..., start:start + n]
    return out


def foh_allpole(gain: np.ndarray, poles: np.ndarray, dt_s: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """FOH difference equations of ``gain / prod(s - p_i)`` in closed form (stacked).

    Each first-order mode ``r / (s - p)`` has the first-order-hold equivalent
    ``r / (p^2 T) [(e^{pT} - 1 - pT) z + (1 - e^{pT} + pT e^{pT})] / (z - e^{pT})``
    (from ``(z - 1)^2 / (T z) Z{H(s) / s^2}``); the modes are summed over a common
    denominator. Poles must be distinct (a repeated pole is nudged apart by 1e-7 relative).

    Parameters
    ----------
    gain : (m,) ndarray
    poles : (m, n) complex ndarray
    dt_s : float

    Returns
    -------
    b, a : (m, n + 1) ndarray
    """
    P = np.array(poles, dtype=complex)
    m, n = P.shape
    scale = np.max(np.abs(P), axis=1, keepdims=True)
    for i in range(n):
        for j in range(i):
            close = np.abs(P[:, i] - P[:, j]) < 1e-7 * scale[:, 0]
            P[close, i] *= 1 + 2e-7
    r = np.array(gain, dtype=complex)[:, None] * np.ones((m, n), complex)
    for i in range(n):
        for j in range(n):
            if i != j:
                r[:, i] /= (P[:, i] - P[:, j])
    T = dt_s
    Phi = np.exp(P * T)
    pT = P * T
    c1 = r / (P ** 2 * T) * (Phi - 1 - pT)
    c0 = r / (P ** 2 * T) * (1 - Phi + pT * Phi)
    den = np.zeros((m, n + 1), complex)
    den[:, 0] = 1.0
    for i in range(n):
        den[:, 1:i + 2] = den[:, 1:i + 2] - Phi[:, i, None] * den[:, 0:i + 1]
    num = np.zeros((m, n + 1), complex)
    for i in range(n):
        # prod_{j != i} (z - Phi_j): degree n - 1
        q = np.zeros((m, n), complex)
        q[:, 0] = 1.0
        deg = 0
        for j in range(n):
            if j == i:
                continue
            q[:, 1:deg + 2] = q[:, 1:deg + 2] - Phi[:, j, None] * q[:, 0:deg + 1]
            deg += 1
        # (c1 z + c0) * q
        num[:, 0:n] += c1[:, i, None] * q
        num[:, 1:n + 1] += c0[:, i, None] * q
    return num.real, den.real


def second_order_poles(wn_rad_s: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """(m, 2) poles of ``s^2 + 2 zeta wn s + wn^2``."""
    wn = np.asarray(wn_rad_s, float)
    z = np.asarray(zeta, float)
    root = np.sqrt((z ** 2 - 1).astype(complex))
    return np.stack([wn * (-z + root), wn * (-z - root)], axis=1)


def second_order_tf(wn_rad_s, zeta, dt_s: float):
    """Stacked FOH difference equations of the unit-gain second-order system."""
    wn = np.asarray(wn_rad_s, float)
    return foh_allpole(wn ** 2, second_order_poles(wn, zeta), dt_s)


def lagged_second_order_tf(wn_rad_s, zeta, tau_s: float, dt_s: float):
    """Stacked FOH difference equations of ``1 / (tau s + 1)`` times the second-order
    system."""
    wn = np.asarray(wn_rad_s, float)
    P = np.concatenate([second_order_poles(wn, zeta),
                        np.full((len(wn), 1), -1.0 / tau_s, complex)], axis=1)
    return foh_allpole(wn ** 2 / tau_s, P, dt_s)


def parallel_tf(b1, a1, b2, a2, weight2: float = 0.5):
    """Stacked ``(1 - w) b1/a1 + w b2/a2`` as one difference equation."""
    m = b1.shape[0]
    n1, n2 = a1.shape[1], a2.shape[1]
    num = np.zeros((m, n1 + n2 - 1))
    den = np.zeros((m, n1 + n2 - 1))
    for i in range(n1):
        for k in range(n2):
            num[:, i + k] += (1 - weight2) * b1[:, i] * a2[:, k] + weight2 * b2[:, k] * a1[:, i]
            den[:, i + k] += a1[:, i] * a2[:, k]
    return num, den


def foh_compensate(x: np.ndarray) -> np.ndarray:
    """Undo the first-order hold's gain droop along the last axis.

    Treating samples as knots of a piecewise-linear input multiplies a sinusoid at
    frequency f by ``sinc^2(f T) ~ 1 - (pi f T)^2 / 3``; the zero-phase 3-tap filter
    ``[-1/12, 7/6, -1/12]`` has gain ``1 + (pi f T)^2 / 3 + O((f T)^4)`` and cancels it
    (residual below 1e-4 at f T = 0.04, i.e. 10 Hz at 250 Hz). The end samples are kept.
    """
    out = x.copy()
    out[..., 1:-1] = (7.0 / 6.0) * x[..., 1:-1] - (x[..., :-2] + x[..., 2:]) / 12.0
    return out
