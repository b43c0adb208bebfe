"""Continuous-time linear models -> difference equations for ``scipy.signal.lfilter``.

The first-order hold (the input is taken as linear between samples) is exact for a
piecewise-linear input and, unlike a zero-order hold, adds no half-sample delay, which would
otherwise look like dead time. The transfer function comes from the discrete state space
through the matrix-determinant lemma: for a single input and output,
``C adj(zI - A) b = det(zI - A + b C) - det(zI - A)``.
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


def _charpoly(M: np.ndarray) -> np.ndarray:
    """Characteristic polynomials of a stack of square matrices, (..., n + 1)."""
    n = M.shape[-1]
    if n == 1:
        return np.stack([np.ones(M.shape[:-2]), -M[..., 0, 0]], axis=-1)
    if n == 2:
        tr = M[..., 0, 0] + M[..., 1, 1]
        det = M[..., 0, 0] * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]
        return np.stack([np.ones_like(tr), -tr, det], axis=-1)
    roots = np.linalg.eigvals(M)
    c = np.zeros(M.shape[:-2] + (n + 1,), dtype=complex)
    c[..., 0] = 1.0
    for k in range(n):
        c[..., 1:k + 2] = c[..., 1:k + 2] - roots[..., k, None] * c[..., 0:k + 1]
    return c.real


def foh_tf_batch(A: np.ndarray, B: np.ndarray, C: np.ndarray, dt_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`foh_tf` for a stack of models: ``A`` (m, n, n), ``B`` and ``C`` (m, n).

    Returns ``b, a`` of shape (m, n + 1).
    """
    m, n = A.shape[0], A.shape[1]
    em = np.zeros((m, n + 2, n + 2))
    em[:, :n, :n] = A * dt_s
    em[:, :n, n] = B * dt_s
    em[:, n, n + 1] = 1.0
    ms = linalg.expm(em)
    ad = ms[:, :n, :n]
    m12 = ms[:, :n, n]
    m13 = ms[:, :n, n + 1]
    bd = m12 - m13 + np.einsum("mij,mj->mi", ad, m13)
    dd = np.einsum("mi,mi->m", C, m13)
    den = _charpoly(ad)
    num = _charpoly(ad - bd[:, :, None] * C[:, None, :]) - den + dd[:, None] * den
    return num, den


def second_order_ss(wn_rad_s: float, zeta: float):
    """Unit-DC-gain ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` as (A, B, C)."""
    A = np.array([[0.0, 1.0], [-wn_rad_s ** 2, -2.0 * zeta * wn_rad_s]])
    B = np.array([0.0, wn_rad_s ** 2])
    C = np.array([1.0, 0.0])
    return A, B, C


def lagged_second_order_ss(wn_rad_s: float, zeta: float, tau_s: float):
    """``1 / (tau s + 1)`` activation lag in front of the unit-gain second-order system."""
    A = np.array([[-1.0 / tau_s, 0.0, 0.0],
                  [0.0, 0.0, 1.0],
                  [wn_rad_s ** 2, -wn_rad_s ** 2, -2.0 * zeta * wn_rad_s]])
    B = np.array([1.0 / tau_s, 0.0, 0.0])
    C = np.array([0.0, 1.0, 0.0])
    return A, B, C


def mixed_second_order_ss(wn_rad_s: float, zeta: float, wn2_rad_s: float, zeta2: float,
                          weight2: float = 0.5):
    """``(1 - w) G(wn, zeta) + w G(wn2, zeta2)``: two muscles with their own dynamics."""
    A = np.zeros((4, 4))
    A[:2, :2] = second_order_ss(wn_rad_s, zeta)[0]
    A[2:, 2:] = second_order_ss(wn2_rad_s, zeta2)[0]
    B = np.array([0.0, wn_rad_s ** 2, 0.0, wn2_rad_s ** 2])
    C = np.array([1.0 - weight2, 0.0, weight2, 0.0])
    return A, B, C


def second_order_batch(wn_rad_s: np.ndarray, zeta: np.ndarray):
    """Stacked :func:`second_order_ss`."""
    m = len(wn_rad_s)
    A = np.zeros((m, 2, 2))
    A[:, 0, 1] = 1.0
    A[:, 1, 0] = -wn_rad_s ** 2
    A[:, 1, 1] = -2.0 * zeta * wn_rad_s
    B = np.zeros((m, 2))
    B[:, 1] = wn_rad_s ** 2
    C = np.zeros((m, 2))
    C[:, 0] = 1.0
    return A, B, C


def lagged_second_order_batch(wn_rad_s: np.ndarray, zeta: np.ndarray, tau_s: float):
    """Stacked :func:`lagged_second_order_ss`."""
    m = len(wn_rad_s)
    A = np.zeros((m, 3, 3))
    A[:, 0, 0] = -1.0 / tau_s
    A[:, 1, 2] = 1.0
    A[:, 2, 0] = wn_rad_s ** 2
    A[:, 2, 1] = -wn_rad_s ** 2
    A[:, 2, 2] = -2.0 * zeta * wn_rad_s
    B = np.zeros((m, 3))
    B[:, 0] = 1.0 / tau_s
    C = np.zeros((m, 3))
    C[:, 1] = 1.0
    return A, B, C


def mixed_second_order_tf(wn_rad_s, zeta, wn2_rad_s, zeta2, dt_s: float,
                          weight2: float = 0.5):
    """FOH difference equations of ``(1 - w) G1 + w G2`` (stacked, exact: the FOH is linear
    in the system, so a parallel connection discretises term by term)."""
    b1, a1 = foh_tf_batch(*second_order_batch(np.asarray(wn_rad_s), np.asarray(zeta)), dt_s)
    b2, a2 = foh_tf_batch(*second_order_batch(np.asarray(wn2_rad_s), np.asarray(zeta2)),
                          dt_s)
    m = b1.shape[0]
    num = np.zeros((m, 5))
    den = np.zeros((m, 5))
    for i in range(3):
        for k in range(3):
            num[:, i + k] += (1 - weight2) * b1[:, i] * a2[:, k] + weight2 * b2[:, i] * a1[:, k]
            den[:, i + k] += a1[:, i] * a2[:, k]
    return num, den


def mixed_second_order_batch(wn_rad_s: np.ndarray, zeta: np.ndarray, wn2_rad_s: np.ndarray,
                             zeta2: np.ndarray, weight2: float = 0.5):
    """Stacked :func:`mixed_second_order_ss`."""
    m = len(wn_rad_s)
    A1, B1, _ = second_order_batch(wn_rad_s, zeta)
    A2, B2, _ = second_order_batch(wn2_rad_s, zeta2)
    A = np.zeros((m, 4, 4))
    A[:, :2, :2] = A1
    A[:, 2:, 2:] = A2
    B = np.concatenate([B1, B2], axis=1)
    C = np.zeros((m, 4))
    C[:, 0] = 1.0 - weight2
    C[:, 2] = weight2
    return A, B, C


def fractional_delay(x: np.ndarray, delay_samples: float) -> np.ndarray:
    """Delay each row by a (fractional) number of samples; zero before the start.

    Integer shift plus a 4-tap Lagrange interpolator (error below 1e-5 of the amplitude for
    content under 5 % of the sampling rate, as here: under 25 Hz at 500 Hz)."""
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
