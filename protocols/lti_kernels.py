"""Linear time-invariant kernels in numpy alone, for the simulator: the zero-order-hold
discretisation of a transfer function and a filter that continues from its past.

``import scipy.signal`` costs 0.5-1 s of a process's start-up (scipy 1.17 wraps and
re-documents every function at import), a third of a whole fast-clock simulated session.
The lowest layer holds what the simulator (:mod:`nmsid.sim_backends.filters`) needs, and the
one :func:`expm` the analysis shares (:mod:`nmsid.analysis.signal_kernels` re-exports it):

* :func:`tf2ss`, :func:`ss2tf` and :func:`cont2discrete_zoh`: ``scipy.signal.cont2discrete``
  with ``method="zoh"`` on a ``(num, den)`` system, the same steps in the same order
  (controller canonical form, :func:`expm` of the augmented matrix, characteristic
  polynomials), so the coefficients agree with scipy's to rounding;
* :func:`expm` (``scipy.linalg.expm`` for the few-state matrices of a hold discretisation);
* :func:`lfilter_history`: ``scipy.signal.lfilter`` with ``zi = lfiltic(b, a, y_past,
  x_past)``, i.e. the difference equation continued from its past inputs and outputs.

:func:`lfilter_history` runs the FIR part as one convolution and the all-pole part in blocks
of :data:`HISTORY_BLOCK` samples: inside a block the response is a product with the
all-pole impulse response (a Toeplitz matrix) plus the free response to the last outputs
of the block before; only those few outputs are carried from block to block, in order.
Unlike a log-depth scan of the direct-form state (``analysis.signal_kernels.lfilter``),
which loses digits when the poles crowd near ``z = 1`` (a slow muscle sampled at 2 kHz: a
3rd-order cascade with ``|1 - p| ~ 1e-3``), it stays as accurate as the sample-by-sample
recursion (tests compare with scipy over the participants' range).
"""

from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["HISTORY_BLOCK", "lfilter_history", "expm", "tf2ss", "ss2tf",
           "cont2discrete_zoh"]

#: samples per block of :func:`lfilter_history` (a 30000-sample trial: 469 carried steps)
HISTORY_BLOCK = 64


def _past(values, n: int) -> np.ndarray:
    """The ``n`` most recent values (most recent first), zero-padded."""
    v = np.zeros(n) if values is None else np.asarray(values, dtype=float).ravel()[:n]
    return v if v.size == n else np.concatenate([v, np.zeros(n - v.size)])


@functools.lru_cache(maxsize=16)
def _differences(N: int) -> np.ndarray:
    """``D`` with ``D @ y_past`` = the backward differences ``y[-1]``, ``y[-1] - y[-2]``,
    ``y[-1] - 2 y[-2] + y[-3]``, ... (signed Pascal matrix: ``D @ D = I``)."""
    D = np.array([[(-1.0) ** j * math.comb(i, j) for j in range(N)] for i in range(N)])
    D.flags.writeable = False
    return D


@functools.lru_cache(maxsize=512)
def _allpole_blocks(a_key: tuple[float, ...], L: int) -> tuple[np.ndarray, np.ndarray]:
    """(``H.T``, ``F``) of the all-pole filter ``1 / a(z)`` (``a[0] == 1``) over ``L``
    samples: ``y = H v + F d`` with ``H`` the lower-triangular Toeplitz matrix of the
    impulse response and ``F`` (L x N) the free response to the backward differences
    ``d = D y_past`` of the past outputs (:func:`_differences`).

    Differences, not the outputs themselves: with poles near ``z = 1`` the free response
    to one past output alone grows like ``k^(N-1)`` and the sum over a smooth past cancels
    (losing ~4 digits a block at 64 samples); the response to a level, a slope, a
    curvature does not cancel. Built by running the recursion itself on N + 1 unit problems
    (read-only: cached per coefficient set)."""
    a = np.asarray(a_key)
    N = a.size - 1
    D = _differences(N)
    y = np.zeros((N + L, N + 1))    # row N + k: sample k; column 0 impulse, j: d_j = 1
    y[N - 1::-1, 1:] = D            # the past (most recent first) whose differences are unit
    ar = a[:0:-1]                   # a_N .. a_1, against rows k .. N + k - 1
    for k in range(L):
        y[N + k] = -(ar @ y[k:N + k])
        if k == 0:
            y[N, 0] += 1.0
    h = y[N:, 0]
    idx = np.arange(L)[:, None] - np.arange(L)[None, :]
    H = np.where(idx >= 0, h[np.clip(idx, 0, L - 1)], 0.0)
    HT, F = np.ascontiguousarray(H.T), np.ascontiguousarray(y[N:, 1:])
    HT.flags.writeable = F.flags.writeable = False
    return HT, F


def lfilter_history(b, a, x, x_past=None, y_past=None) -> np.ndarray:
    """Filter ``x`` with ``b(z) / a(z)``, continuing from past inputs and outputs.

    The same as ``scipy.signal.lfilter(b, a, x, zi=scipy.signal.lfiltic(b, a, y_past,
    x_past))`` to rounding: ``y[k] = sum_j b_j x[k-j] - sum_{j>=1} a_j y[k-j]`` with
    ``x[-1], x[-2], ...`` from ``x_past`` and ``y[-1], ...`` from ``y_past``.

    Parameters
    ----------
    b, a : array_like
        Numerator and denominator coefficients (``a[0] != 0``).
    x : array_like
        1-D input.
    x_past, y_past : array_like, optional
        Past inputs and outputs, most recent first; zeros if not given, zero-padded.

    Returns
    -------
    y : ndarray
        Output, the length of ``x``.

    Examples
    --------
    >>> import numpy as np
    >>> y = lfilter_history([0.5], [1.0, -0.5], np.ones(4), y_past=[1.0])  # at rest at 1
    >>> y.tolist()
    [1.0, 1.0, 1.0, 1.0]
    """
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.ndim != 1 or b.ndim != 1 or a.size == 0 or b.size == 0:
        raise ValueError("b and a must be non-empty 1-D coefficient arrays")
    if a[0] == 0:
        raise ValueError("a[0] must not be 0")
    b, a = b / a[0], a / a[0]
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    M, N, T = b.size - 1, a.size - 1, x.size
    if T == 0:
        return np.zeros(0)
    xe = np.concatenate([_past(x_past, M)[::-1], x])
    v = np.convolve(xe, b)[M:M + T]            # the FIR part, from the past inputs
    if N == 0:
        return v
    L = max(HISTORY_BLOCK, N)
    HT, F = _allpole_blocks(tuple(a.tolist()), L)
    K, r = divmod(T, L)
    y = np.empty(T)
    tail = _past(y_past, N)                    # the last N outputs, most recent first
    if K:
        # np.einsum, not @: numpy's own loops (0.4 ms for a 30000-sample trial) instead of
        # BLAS, whose worker threads spin after every call (a session: 4.4 s of CPU instead
        # of 2.4 s on 2 cores, for the same wall time)
        g = np.einsum("kl,lm->km", v[:K * L].reshape(K, L), HT)   # each block from rest
        last = np.arange(L - 1, L - N - 1, -1)    # the last N samples, most recent first
        G = np.ascontiguousarray(F[last])
        g_tail = np.ascontiguousarray(g[:, last])
        D = _differences(N)
        starts = np.empty((K, N))              # each block's past, as differences
        for k in range(K):                     # in order: the few carried outputs
            d = D @ tail                       # exact: differences of close numbers
            starts[k] = d
            tail = g_tail[k] + G @ d
        y[:K * L] = (g + np.einsum("kn,ln->kl", starts, F)).ravel()
    if r:
        y[K * L:] = (np.einsum("l,lm->m", v[K * L:], HT[:r, :r])
                     + F[:r] @ (_differences(N) @ tail))
    return y


def expm(M) -> np.ndarray:
    """Matrix exponential by scaling and squaring with a [6/6] Pade approximant.

    For the small matrices of a hold discretisation (a few states, ``|M| ~ 0.1``) this is
    exact to rounding (tests compare with ``scipy.linalg.expm``); Higham 2005, "The
    scaling and squaring method for the matrix exponential revisited", SIAM J Matrix
    Anal Appl 26:1179, with the scaling chosen so that ``|M / 2^s|_1 <= 0.5``.
    """
    A = np.asarray(M, dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"expm needs a square matrix, got shape {A.shape}")
    norm = float(np.max(np.sum(np.abs(A), axis=0))) if A.size else 0.0
    squarings = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    A = A / 2.0 ** squarings
    q = 6
    c = [math.factorial(2 * q - k) * math.factorial(q)
         / (math.factorial(2 * q) * math.factorial(k) * math.factorial(q - k))
         for k in range(q + 1)]
    eye = np.eye(A.shape[0])
    power = eye
    N = c[0] * eye
    D = c[0] * eye
    for k in range(1, q + 1):
        power = power @ A
        N = N + c[k] * power
        D = D + (-1) ** k * c[k] * power
    X = np.linalg.solve(D, N)
    for _ in range(squarings):
        X = X @ X
    return X


def tf2ss(num, den) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Controller canonical state space of ``num(s) / den(s)`` (``scipy.signal.tf2ss``,
    single input, single output).

    Returns
    -------
    A, B, C, D : ndarray
        ``(n, n)``, ``(n, 1)``, ``(1, n)``, ``(1, 1)`` with ``n = len(den) - 1``.

    Raises
    ------
    ValueError
        For an improper transfer function (``num`` longer than ``den``) or a zero ``den``.
    """
    num = np.atleast_1d(np.asarray(num, dtype=float))
    den = np.atleast_1d(np.asarray(den, dtype=float))
    if num.ndim != 1 or den.ndim != 1:
        raise ValueError("num and den must be 1-D polynomial coefficient arrays")
    if not np.any(den != 0):
        raise ValueError("the denominator must have a non-zero coefficient")
    den = np.trim_zeros(den, "f")
    num, den = num / den[0], den / den[0]
    lead = 0                      # scipy.signal.normalize: leading |num| <= 1e-14 dropped
    while lead < num.size - 1 and abs(num[lead]) <= 1e-14:
        lead += 1
    num = num[lead:]
    M, K = num.size, den.size
    if M > K:
        raise ValueError("improper transfer function: num is longer than den")
    num = np.concatenate([np.zeros(K - M), num])[None, :]
    D = np.atleast_2d(num[:, 0])
    if K == 1:
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), D.reshape(1, 1)
    A = np.vstack([-den[None, 1:], np.eye(K - 2, K - 1)])
    B = np.eye(K - 1, 1)
    C = num[:, 1:] - np.outer(num[:, 0], den[1:])
    return A, B, C, D.reshape(1, 1)


def ss2tf(A, B, C, D) -> tuple[np.ndarray, np.ndarray]:
    """Transfer function of a single-input, single-output state space
    (``scipy.signal.ss2tf``): ``den = poly(A)``, ``num = poly(A - B C) + (D - 1) den``.

    Returns
    -------
    num : ndarray
        Shape ``(1, n + 1)`` as scipy's (its first coefficient is zero up to rounding for a
        strictly proper system).
    den : ndarray
        Shape ``(n + 1,)``.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.atleast_2d(np.asarray(B, dtype=float))
    C = np.atleast_2d(np.asarray(C, dtype=float))
    D = np.atleast_2d(np.asarray(D, dtype=float))
    den = np.poly(A)
    num = np.empty((1, A.shape[0] + 1))
    num[0] = np.poly(A - B @ C) + (D[0, 0] - 1.0) * den
    return num, den


def cont2discrete_zoh(num, den, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of ``num(s) / den(s)`` with sample time ``dt_s``
    (``scipy.signal.cont2discrete((num, den), dt_s, method="zoh")[:2]``).

    Exact for a staircase input: ``[[Ad, Bd], [0, I]] = expm(dt [[A, B], [0, 0]])``.

    Returns
    -------
    num_d : ndarray
        Shape ``(1, n + 1)``, as scipy's.
    den_d : ndarray
        Shape ``(n + 1,)``.

    Examples
    --------
    >>> import numpy as np
    >>> b, a = cont2discrete_zoh([1.0], [1.0, 1.0], 0.1)   # 1 / (s + 1)
    >>> np.round(b, 6).tolist(), np.round(a, 6).tolist()
    ([[0.0, 0.095163]], [1.0, -0.904837])
    """
    if not dt_s > 0:
        raise ValueError(f"sample time dt_s = {dt_s!r} must be > 0")
    A, B, C, D = tf2ss(num, den)
    n, m = A.shape[0], B.shape[1]
    em = np.vstack([np.hstack([A, B]), np.zeros((m, n + m))])
    ms = expm(dt_s * em)[:n, :]
    return ss2tf(ms[:, :n], ms[:, n:], C, D)
