"""Exact sampled-data form of the second-order model, for fast simulation with ``lfilter``.

The continuous model ``G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (unit gain; Kp multiplies
it) is discretised with a first-order (triangle) hold: between samples the input is a
straight line, and the state is propagated by the matrix exponential, so for such an input
the discrete model is exact, whatever the sampling rate and damping (critical damping
included: no eigen-decomposition is used). The result is a transfer function
``N(z^-1) / D(z^-1)`` with three numerator and three denominator coefficients, run by
``scipy.signal.lfilter``.

The same module holds the stacked first-order-hold difference equations of the gap
diagnosis's augmented models (:func:`foh_allpole` and the functions built on it, vectorised
over sE levels) and the fractional delay of either sign that carries the rig's input timing
(:func:`fractional_delay`, see :mod:`nmsid.analysis.input_timing`): identification and gap
diagnosis discretise through this one module.

For a sampled *smooth* input (rE is one), :func:`smooth_hold_input` pre-corrects the
samples so that the piecewise-linear interpolation reproduces the band-limited signal to
sixth order in f/fs (see :class:`nmsid.analysis.settings.InputHold`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

#: Relative step of the central differences used for coefficient derivatives.
_FD_STEP = 1e-6


def _decay_cos_sin(sigma: float, wd2: float, t: float) -> tuple[float, float]:
    """e^{-sigma t} cos(wd t) and e^{-sigma t} sin(wd t) / wd for wd^2 = wd2 of any sign
    (cosh / sinh when overdamped, the limit t e^{-sigma t} at critical damping)."""
    a2 = wd2 * t * t
    e = math.exp(-sigma * t)
    if abs(a2) < 1e-6:   # series: exact to ~1e-19 relative
        return (e * (1 - a2 / 2 + a2 * a2 / 24 - a2 ** 3 / 720),
                e * t * (1 - a2 / 6 + a2 * a2 / 120 - a2 ** 3 / 5040))
    if wd2 > 0:
        w = math.sqrt(wd2)
        return e * math.cos(w * t), e * math.sin(w * t) / w
    w = math.sqrt(-wd2)
    ep = math.exp((w - sigma) * t)     # never overflows: w < sigma for a stable system
    em = math.exp(-(w + sigma) * t)
    return (ep + em) / 2, (ep - em) / (2 * w)


def foh_coefficients(wn_rad_s: float, zeta: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (each length 3) of the triangle-hold discretisation.

    Closed form of the matrix exponential of the 2x2 system (no ``expm``, no BLAS):
    ``e^{At} = e^{-sigma t} (cos(wd t) I + sin(wd t)/wd (A + sigma I))`` with
    ``sigma = zeta wn``, ``wd^2 = wn^2 - sigma^2`` of either sign; the hold integrals are
    ``A^-1 (Phi - I) B`` and ``(A^-2 (Phi - I) - h A^-1) B / h``.

    Parameters
    ----------
    wn_rad_s : float
        Natural angular frequency in rad/s (> 0).
    zeta : float
        Damping ratio (> 0; under-, critically and over-damped all work).
    dt_s : float
        Sampling interval in s.

    Returns
    -------
    num, den : ndarray
        ``y = lfilter(num, den, u)`` is the unit-gain response to the piecewise-linear
        input through the samples ``u`` (zero initial state); ``den[0] == 1`` and
        ``sum(num) / sum(den) == 1`` (unit static gain).

    Examples
    --------
    >>> num, den = foh_coefficients(20.0, 0.5, 1e-3)
    >>> round(float(num.sum() / den.sum()), 12)
    1.0
    """
    n0, n1, n2, d1, d2 = _foh_floats(wn_rad_s, zeta, dt_s)
    return np.array([n0, n1, n2]), np.array([1.0, d1, d2])


def _foh_floats(wn_rad_s: float, zeta: float, h: float
                ) -> tuple[float, float, float, float, float]:
    """:func:`foh_coefficients` as plain floats ``(n0, n1, n2, d1, d2)`` (``d0 = 1``): the
    same operations in the same order (so the same numbers), without building arrays."""
    wn2 = wn_rad_s * wn_rad_s
    sigma = zeta * wn_rad_s
    ec, es = _decay_cos_sin(sigma, wn2 - sigma * sigma, h)
    p11 = ec + sigma * es
    p12 = es
    p21 = -wn2 * es
    p22 = ec - sigma * es
    one_minus_p11 = 1.0 - p11
    if wn2 * h * h < 1e-4:
        # 1 - p11 and the hold integral lose digits to cancellation: use their series
        # (terms of the exponential's Taylor series of the state-space matrices)
        ga0, ga1 = _hold_integrals_series(wn_rad_s, zeta, h)
        gb0, gb1 = _hold_integrals_series(wn_rad_s, zeta, h, second=True)
    else:
        ga0, ga1 = one_minus_p11, -p21
        gb0, gb1 = ((-2 * sigma * one_minus_p11 + p21) / wn2 + h) / h, one_minus_p11 / h
    g00, g01 = ga0 - gb0, ga1 - gb1          # multiply u_k
    # y = C x with C = [1, 0]; N(z) = C adj(zI - Phi) (g0 + g1 z), D(z) = det(zI - Phi)
    # (g1 = g_b multiplies u_{k+1})
    return (gb0, g00 - p22 * gb0 + p12 * gb1, p12 * g01 - p22 * g00,
            -(p11 + p22), p11 * p22 - p12 * p21)


def _hold_integrals_series(wn_rad_s: float, zeta: float, h: float, second: bool = False,
                           terms: int = 12) -> tuple[float, float]:
    """Hold integrals by their Taylor series (for wn h small).

    ``int_0^h e^{As} B ds = sum_k A^k B h^{k+1}/(k+1)!`` and
    ``(1/h) int_0^h e^{As} B (h - s) ds = sum_k A^k B h^{k+1}/(k+2)!``.
    """
    a11, a12, a21, a22 = 0.0, 1.0, -wn_rad_s ** 2, -2 * zeta * wn_rad_s
    x0, x1 = 0.0, wn_rad_s ** 2          # A^k B, k = 0
    total0 = total1 = 0.0
    fact = 1.0                            # (k + 1)! or (k + 2)!
    hp = h                                # h^{k+1}
    for k in range(terms):
        fact *= (k + 2) if second else (k + 1)
        total0 += x0 * hp / fact
        total1 += x1 * hp / fact
        x0, x1 = a11 * x0 + a12 * x1, a21 * x0 + a22 * x1
        hp *= h
    return total0, total1


def foh_coefficients_with_derivatives(log_wn: float, log_zeta: float, dt_s: float):
    """Coefficients and their derivatives with respect to ``ln wn`` and ``ln zeta``.

    Derivatives are central differences of the (smooth, cheap) coefficient map; their
    relative error is ~1e-10, far below anything the fit can resolve. The last few
    answers are kept (read-only arrays): the fits of a level's repeats start from the
    level's optimum, where the level's own fit ended.

    Returns
    -------
    num, den : ndarray (3,)
    dnum, dden : ndarray (2, 3)
        Row j is the derivative with respect to parameter j (ln wn, ln zeta).
    """
    return _foh_derivatives(float(log_wn), float(log_zeta), float(dt_s))


@functools.lru_cache(maxsize=64)
def _foh_derivatives(log_wn: float, log_zeta: float, dt_s: float):
    """:func:`foh_coefficients_with_derivatives`, kept for the last 64 arguments (a
    thread-safe cache; the arrays are read-only)."""
    p = (log_wn, log_zeta)
    num = _foh_floats(math.exp(p[0]), math.exp(p[1]), dt_s)
    diffs = []
    for j in range(2):
        step = _FD_STEP * max(1.0, abs(p[j]))
        hi = list(p)
        lo = list(p)
        hi[j] += step
        lo[j] -= step
        c_hi = _foh_floats(math.exp(hi[0]), math.exp(hi[1]), dt_s)
        c_lo = _foh_floats(math.exp(lo[0]), math.exp(lo[1]), dt_s)
        two = 2 * step
        # (hi - lo) / (2 step) per coefficient; d(den[0]) = (1 - 1) / (2 step) = 0
        diffs.append([(c_hi[i] - c_lo[i]) / two for i in range(5)])
    dnum = np.array([[d[0], d[1], d[2]] for d in diffs])
    dden = np.array([[0.0, d[3], d[4]] for d in diffs])
    out = (np.array(num[:3]), np.array([1.0, num[3], num[4]]), dnum, dden)
    for arr in out:
        arr.flags.writeable = False
    return out


def smooth_hold_input(u: np.ndarray) -> np.ndarray:
    """Pre-correct samples of a smooth signal for a piecewise-linear (triangle) hold.

    The triangle hold passes a sinusoid of frequency f with gain sinc^2(f dt). The FIR
    ``v = u - D2 u / 12 + D4 u / 90`` (D2, D4: second and fourth central differences) has
    gain 1 + x^2/3 + x^4/15 + O(x^6) with x = pi f dt, the series of 1/sinc^2, so the
    held ``v`` equals the band-limited ``u`` to O(x^6): 1e-6 at 10 Hz sampled at 200 Hz.
    The two samples at each end use an odd (point) reflection of the signal, which keeps
    straight lines exact. Works along the last axis of an array of any shape.

    Examples
    --------
    >>> import numpy as np
    >>> np.allclose(smooth_hold_input(np.arange(10.0)), np.arange(10.0))
    True
    """
    u = np.asarray(u, dtype=float)
    if u.shape[-1] < 5:
        return u.copy()
    left = 2 * u[..., :1] - u[..., 2:0:-1]
    right = 2 * u[..., -1:] - u[..., -2:-4:-1]
    p = np.concatenate([left, u, right], axis=-1)
    c = p[..., 2:-2]
    d2 = p[..., 3:-1] - 2 * c + p[..., 1:-3]
    d4 = p[..., 4:] - 4 * p[..., 3:-1] + 6 * c - 4 * p[..., 1:-3] + p[..., :-4]
    return c - d2 / 12.0 + d4 / 90.0


def foh_state_matrices(wn_rad_s, zeta, dt_s: float):
    """Vectorised triangle-hold state-space matrices of ``y'' + 2 zeta wn y' + wn^2 y =
    wn^2 w`` with state [y, y'] (for time-varying simulation).

    ``x_{k+1} = Phi x_k + G0 w_k + G1 w_{k+1}`` is exact for ``w`` linear between samples.

    Parameters
    ----------
    wn_rad_s, zeta : array-like (same shape, any)
    dt_s : float

    Returns
    -------
    phi : ndarray (..., 2, 2)
    g0, g1 : ndarray (..., 2)

    Examples
    --------
    >>> import numpy as np
    >>> phi, g0, g1 = foh_state_matrices(np.array([30.0]), np.array([1.0]), 1e-3)
    >>> bool(np.allclose((np.eye(2) - phi[0]) @ np.array([1.0, 0.0]), g0[0] + g1[0]))
    True
    """
    wn = np.asarray(wn_rad_s, dtype=float)
    z = np.asarray(zeta, dtype=float)
    wn, z = np.broadcast_arrays(wn, z)
    h = float(dt_s)
    wn2 = wn * wn
    sigma = z * wn
    wd2 = wn2 - sigma * sigma
    a2 = wd2 * h * h
    e = np.exp(-sigma * h)
    with np.errstate(all="ignore"):
        w_pos = np.sqrt(np.abs(wd2))
        ec = np.where(wd2 > 0, e * np.cos(w_pos * h),
                      (np.exp((w_pos - sigma) * h) + np.exp(-(w_pos + sigma) * h)) / 2)
        es = np.where(wd2 > 0, e * np.sin(w_pos * h) / np.where(w_pos > 0, w_pos, 1.0),
                      (np.exp((w_pos - sigma) * h) - np.exp(-(w_pos + sigma) * h))
                      / (2 * np.where(w_pos > 0, w_pos, 1.0)))
    small = np.abs(a2) < 1e-6
    ec = np.where(small, e * (1 - a2 / 2 + a2 * a2 / 24 - a2 ** 3 / 720), ec)
    es = np.where(small, e * h * (1 - a2 / 6 + a2 * a2 / 120 - a2 ** 3 / 5040), es)
    phi = np.empty(wn.shape + (2, 2))
    phi[..., 0, 0] = ec + sigma * es
    phi[..., 0, 1] = es
    phi[..., 1, 0] = -wn2 * es
    phi[..., 1, 1] = ec - sigma * es
    # hold integrals by series (exact to rounding for wn h < ~2); closed form otherwise
    ga_s, gb_s = np.zeros(wn.shape + (2,)), np.zeros(wn.shape + (2,))
    x0, x1 = np.zeros_like(wn), wn2.copy()
    fa = fb = 1.0
    hp = h
    for k in range(30):
        fa *= k + 1
        fb *= k + 2
        ga_s[..., 0] += x0 * hp / fa
        ga_s[..., 1] += x1 * hp / fa
        gb_s[..., 0] += x0 * hp / fb
        gb_s[..., 1] += x1 * hp / fb
        x0, x1 = x1, -wn2 * x0 - 2 * sigma * x1
        hp *= h
    one_m = 1.0 - phi[..., 0, 0]
    with np.errstate(all="ignore"):
        ga_c = np.stack([one_m, -phi[..., 1, 0]], axis=-1)
        gb_c = np.stack([((-2 * sigma * one_m + phi[..., 1, 0]) / wn2 + h) / h, one_m / h],
                        axis=-1)
    use_series = (wn * h < 2.0)[..., None]
    ga = np.where(use_series, ga_s, ga_c)
    gb = np.where(use_series, gb_s, gb_c)
    return phi, ga - gb, gb


def fractional_delay(x: np.ndarray, delay_samples: float) -> np.ndarray:
    """Delay each row by a fractional number of samples of either sign.

    Integer shift plus a 4-tap Lagrange (cubic) interpolator: error below 1e-5 of the
    amplitude for content under 5 % of the sampling rate. A positive delay repeats the
    first sample before the start (the rig's input was at rest there); a negative delay
    (an advance) repeats the last sample after the end.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.arange(10.0)
    >>> bool(np.allclose(fractional_delay(x, 0.5)[3:-2], x[3:-2] - 0.5))
    True
    >>> bool(np.allclose(fractional_delay(x, -1.25)[:6], x[:6] + 1.25))
    True
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    k = int(np.floor(delay_samples))
    mu = float(delay_samples - k)
    # output sample i = x(i - k - mu): Lagrange through x[i-k+1], x[i-k], x[i-k-1], x[i-k-2]
    c = (-mu * (mu - 1) * (mu - 2) / 6, (mu + 1) * (mu - 1) * (mu - 2) / 2,
         -(mu + 1) * mu * (mu - 2) / 2, (mu + 1) * mu * (mu - 1) / 6)
    pad = abs(k) + 3
    xp = np.concatenate([np.repeat(x[..., :1], pad, axis=-1), x,
                         np.repeat(x[..., -1:], pad, axis=-1)], axis=-1)
    out = np.zeros_like(x)
    for tap, shift in zip(c, (k - 1, k, k + 1, k + 2), strict=True):
        start = pad - shift
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
