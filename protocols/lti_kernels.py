"""Linear time-invariant kernels of the lowest layer: the zero-order-hold discretisation
of a transfer function, the product's one recursive filter, and a filter that continues
from its past.

``import scipy.signal`` costs 0.5-1 s of a process's start-up (scipy 1.17 wraps and
re-documents every function at import), a third of a whole fast-clock simulated session.
The lowest layer holds what the simulator (:mod:`nmsid.sim_backends.filters`) needs, the
filter every layer above runs, and the one :func:`expm` the analysis shares
(:mod:`nmsid.analysis.signal_kernels` re-exports it):

* :func:`tf2ss`, :func:`ss2tf` and :func:`cont2discrete_zoh`: ``scipy.signal.cont2discrete``
  with ``method="zoh"`` on a ``(num, den)`` system, the same steps in the same order
  (controller canonical form, :func:`expm` of the augmented matrix, characteristic
  polynomials), so the coefficients agree with scipy's to rounding;
* :func:`expm` (``scipy.linalg.expm`` for the few-state matrices of a hold discretisation);
* :func:`lfilter`: the product's one recursive filter, ``scipy.signal.lfilter`` itself:
  scipy's compiled kernel (``_linear_filter`` in ``scipy/signal/_sigtools``) loaded from its
  extension file in ~0.2 ms, without ``import scipy.signal`` (bit-identical to
  ``scipy.signal.lfilter``: the same compiled code), and :func:`lfiltic`;
* :func:`sosfilt`: ``scipy.signal.sosfilt``, the same way (scipy's compiled ``_sosfilt``
  from ``scipy/signal/_sosfilt``: every sample through all sections in one pass over the
  data, ~2x faster than the sections one after the other through :func:`lfilter`);
* :func:`lfilter_history`: ``scipy.signal.lfilter`` with ``zi = lfiltic(b, a, y_past,
  x_past)``, i.e. the difference equation continued from its past inputs and outputs.

The analysis (:mod:`nmsid.analysis.signal_kernels`, the gap fits) and the simulator filter
through :func:`lfilter`. The kernel's module name is private to scipy: when it cannot be
found or loaded (another scipy layout), :func:`kernel_available` (and
:func:`sos_kernel_available`) says so and each caller
keeps a numpy fallback (the analysis: its block scan; :func:`lfilter` itself: the public
``scipy.signal.lfilter``, at ``import scipy.signal``'s cost). The fallback of
:func:`lfilter_history` is a numpy recursion: it runs the FIR part as one convolution
and the all-pole part in blocks of :data:`HISTORY_BLOCK` samples: inside a block the
response is a product with the all-pole impulse response (a Toeplitz matrix) plus the free
response to the last outputs of the block before; only those few outputs are carried from
block to block, in order. Unlike a log-depth scan of the direct-form state (the
fallback of ``analysis.signal_kernels.lfilter``),
which loses digits when the poles crowd near ``z = 1`` (a slow muscle sampled at 2 kHz: a
3rd-order cascade with ``|1 - p| ~ 1e-3``), it stays as accurate as the sample-by-sample
recursion (tests compare with scipy over the participants' range).
"""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
import math
import sys
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["HISTORY_BLOCK", "lfilter", "lfiltic", "kernel_available", "lfilter_history",
           "sosfilt", "sos_kernel_available", "sosfilt_rows_inplace", "expm", "tf2ss", "ss2tf", "cont2discrete_zoh"]

_kernel: Callable | None = None
#: "compiled kernel" or "unavailable" once the first call chose (for tests and bench/).
source: str | None = None
_sos_kernel: Callable | None = None
#: the same for :func:`sosfilt`'s kernel (scipy's ``_sosfilt``).
sos_source: str | None = None


def _load_extension(stem: str, function: str) -> Callable | None:
    """``function`` of scipy's compiled extension ``scipy/signal/<stem><suffix>`` loaded
    from its file, or None (nothing registered in ``sys.modules``: a later ``import
    scipy.signal`` loads scipy as usual). Every suffix of
    ``importlib.machinery.EXTENSION_SUFFIXES`` is tried (``.pyd`` etc. on Windows)."""
    try:
        import scipy  # the package's own start-up only (~5 ms; on Windows, its DLL paths)
    except ImportError:
        return None
    name = f"scipy.signal.{stem}"
    folder = Path(scipy.__file__).parent / "signal"
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:  # ".pyd" etc. on Windows
        path = folder / (stem + suffix)
        if not path.is_file():
            continue
        had = name in sys.modules
        try:
            # the extension loader named, not guessed from the suffix: the same on every OS
            loader = importlib.machinery.ExtensionFileLoader(name, str(path))
            spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
            if spec is None or spec.loader is None:
                return None
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        except Exception:  # noqa: BLE001 - any failure: the caller's fallback instead
            return None
        finally:
            if not had:  # a single-phase module registers itself; scipy re-imports it
                sys.modules.pop(name, None)
        fn = getattr(module, function, None)
        return fn if callable(fn) else None
    return None


def _load_kernel() -> Callable | None:
    """scipy's ``_linear_filter(b, a, x, axis[, zi])`` loaded from its extension file
    (``scipy/signal/_sigtools``), or None."""
    return _load_extension("_sigtools", "_linear_filter")


def _load_sos_kernel() -> Callable | None:
    """scipy's ``_sosfilt(sos, x, zi)`` loaded from its extension file
    (``scipy/signal/_sosfilt``, Cython), or None.

    ``scipy/signal/_sosfilt.pyx`` (scipy 1.17): ``_sosfilt(sos[:, ::1], x[:, ::1],
    zi[:, :, ::1])`` filters every row of ``x`` in place through the sections in
    transposed direct form II, sample by sample (each sample through all sections before
    the next), updating ``zi`` (rows x sections x 2) in place; it assumes ``sos[:, 3] ==
    1`` (it never reads that column). ``scipy.signal.sosfilt`` calls it on a C-ordered
    float copy of ``x`` moved to the last axis and reshaped to rows."""
    return _load_extension("_sosfilt", "_sosfilt")


def _compiled() -> Callable | None:
    """The compiled kernel, or None; chosen once per process."""
    global _kernel, source
    if source is None:
        _kernel = _load_kernel()
        source = "compiled kernel" if _kernel is not None else "unavailable"
    return _kernel


def _compiled_sos() -> Callable | None:
    """The compiled second-order-sections kernel, or None; chosen once per process."""
    global _sos_kernel, sos_source
    if sos_source is None:
        _sos_kernel = _load_sos_kernel()
        sos_source = "compiled kernel" if _sos_kernel is not None else "unavailable"
    return _sos_kernel


def kernel_available() -> bool:
    """Whether :func:`lfilter` runs scipy's compiled kernel without ``import scipy.signal``
    (else callers use their numpy fallback)."""
    return _compiled() is not None


def sos_kernel_available() -> bool:
    """Whether :func:`sosfilt` runs scipy's compiled ``_sosfilt`` without ``import
    scipy.signal`` (else callers use their fallback)."""
    return _compiled_sos() is not None


def sosfilt_rows_inplace(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> bool:
    """Filter the rows of ``x`` through ``sos`` in place, from and updating the states
    ``zi``, with scipy's compiled ``_sosfilt`` (what ``scipy.signal.sosfilt`` runs once it
    has prepared its arrays): for callers that prepared theirs (a zero-phase filter builds
    its padded rows once and filters them where they are).

    Parameters
    ----------
    sos : ndarray
        ``(n_sections, 6)`` float64, C-contiguous, ``sos[:, 3] == 1`` (not checked).
    x : ndarray
        ``(rows, samples)`` float64, C-contiguous, writeable: overwritten by the output.
    zi : ndarray
        ``(rows, n_sections, 2)`` float64, C-contiguous: overwritten by the final states.

    Returns
    -------
    bool
        False (nothing done) when the kernel cannot be loaded.
    """
    kernel = _compiled_sos()
    if kernel is None:
        return False
    kernel(sos, x, zi)
    return True


def _coefficients(b, a) -> tuple[np.ndarray, np.ndarray]:
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.ndim != 1 or b.ndim != 1 or a.size == 0 or b.size == 0:
        raise ValueError(f"lfilter: b and a must be non-empty 1-D coefficient arrays "
                         f"(b.shape={b.shape}, a.shape={a.shape})")
    if a[0] == 0:
        raise ValueError("lfilter: a[0] must not be 0")
    return b, a


def lfilter(b, a, x, axis: int = -1, zi=None):
    """``scipy.signal.lfilter(b, a, x, axis, zi)`` for real float64 data, without
    ``import scipy.signal``.

    Runs scipy's own compiled kernel (transposed direct form II, normalised by ``a[0]``):
    the result is bit-identical to ``scipy.signal.lfilter``'s. A pure FIR (``len(a) ==
    1``) is the convolution scipy runs. When the kernel cannot be loaded, the public
    ``scipy.signal.lfilter`` is called instead (the same numbers; only start-up is lost).

    Parameters
    ----------
    b, a : array_like
        Numerator and denominator coefficients (1-D, non-empty, ``a[0] != 0``).
    x : array_like
        Input, filtered along ``axis`` (computed in float64).
    axis : int
    zi : array_like, optional
        Initial DF2T states: x's shape with ``axis`` of length ``max(len(a), len(b)) - 1``
        (other axes may be 1, as scipy's).

    Returns
    -------
    y : ndarray
        Output, x's shape. With ``zi``: ``(y, zf)``.

    Raises
    ------
    ValueError
        For coefficients that are not 1-D and non-empty, ``a[0] == 0``, or a ``zi`` of
        another shape.

    Examples
    --------
    >>> import numpy as np
    >>> y = lfilter([0.5], [1.0, -0.5], np.ones(4))   # 1st-order low-pass, unit DC gain
    >>> y.tolist()
    [0.5, 0.75, 0.875, 0.9375]
    """
    b, a = _coefficients(b, a)
    x = np.asarray(x, dtype=float)
    if zi is not None:
        zi = np.asarray(zi, dtype=float)
    if a.size == 1:                  # FIR: scipy's own convolution path, the same steps
        b = b / a[0]
        full = np.apply_along_axis(lambda v: np.convolve(b, v), axis, x)
        ind = full.ndim * [slice(None)]
        if zi is not None:
            if zi.shape[axis] != b.size - 1 or zi.ndim != x.ndim:
                raise ValueError(f"lfilter: zi has shape {zi.shape}; expected x's shape "
                                 f"with axis {axis} of length {b.size - 1}")
            ind[axis] = slice(zi.shape[axis])
            full[tuple(ind)] += zi
        n = full.shape[axis] - b.size + 1
        ind[axis] = slice(n)
        y = full[tuple(ind)]
        if zi is None:
            return y
        ind[axis] = slice(n, None)
        return y, full[tuple(ind)]
    kernel = _compiled()
    if kernel is None:
        import scipy.signal  # the fallback: the same kernel behind the public function
        return scipy.signal.lfilter(b, a, x, axis=axis, zi=zi)
    if zi is None:
        return kernel(b, a, x, axis)
    return kernel(b, a, x, axis, zi)


def lfiltic(b, a, y, x=None) -> np.ndarray:
    """Initial DF2T states from past outputs ``y`` and inputs ``x`` (most recent first):
    ``scipy.signal.lfiltic``, the same sums in the same order.

    Examples
    --------
    >>> lfiltic([0.5], [1.0, -0.5], [1.0]).tolist()   # at rest at 1: y[-1] = 1
    [0.5]
    """
    b, a = _coefficients(b, a)
    N, M = a.size - 1, b.size - 1
    K = max(M, N)
    x = np.zeros(M) if x is None else np.asarray(x, dtype=float).ravel()
    if x.size < M:
        x = np.concatenate([x, np.zeros(M - x.size)])
    y = np.asarray(y, dtype=float).ravel()
    if y.size < N:
        y = np.concatenate([y, np.zeros(N - y.size)])
    zi = np.zeros(K)
    for m in range(M):
        zi[m] = np.sum(b[m + 1:] * x[:M - m], axis=0)
    for m in range(N):
        zi[m] -= np.sum(a[m + 1:] * y[:N - m], axis=0)
    if a[0] != 1.0:
        zi /= a[0]
    return zi

def sosfilt(sos, x, axis: int = -1, zi=None):
    """``scipy.signal.sosfilt(sos, x, axis, zi)`` for real float64 data, without ``import
    scipy.signal``: the same preparation of the arrays and scipy's own compiled kernel
    (:func:`_load_sos_kernel`), so the result is bit-identical to scipy's.

    When the kernel cannot be loaded, the public ``scipy.signal.sosfilt`` is called
    instead (the same numbers; only start-up is lost).

    Parameters
    ----------
    sos : array_like
        ``(n_sections, 6)`` second-order sections ``[b0, b1, b2, 1, a1, a2]``.
    x : array_like
        Input, filtered along ``axis`` (computed in float64).
    axis : int
    zi : array_like, optional
        Initial states, shape ``(n_sections, ..., 2, ...)``: x's shape with ``axis`` of
        length 2, after a first axis of the sections (as scipy's, no broadcasting).

    Returns
    -------
    y : ndarray
        Output, x's shape. With ``zi``: ``(y, zf)``, ``zf`` of ``zi``'s shape.

    Raises
    ------
    ValueError
        For ``sos`` not of shape ``(n_sections, 6)``, ``sos[:, 3]`` not all 1, or a
        ``zi`` of another shape (scipy's checks).

    Examples
    --------
    >>> import numpy as np
    >>> sos = [[0.5, 0.0, 0.0, 1.0, -0.5, 0.0]]   # 1st-order low-pass, unit DC gain
    >>> sosfilt(sos, np.ones(4)).tolist()
    [0.5, 0.75, 0.875, 0.9375]
    """
    sos = np.atleast_2d(np.asarray(sos, dtype=float))
    if sos.ndim != 2 or sos.shape[1] != 6:
        raise ValueError(f"sosfilt: sos must have shape (n_sections, 6), got {sos.shape}")
    if not np.all(sos[:, 3] == 1):
        raise ValueError("sosfilt: sos[:, 3] (each section's a0) must all be 1")
    kernel = _compiled_sos()
    if kernel is None:
        import scipy.signal  # the fallback: the same kernel behind the public function
        return scipy.signal.sosfilt(sos, x, axis=axis, zi=zi)
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        raise ValueError("sosfilt: x must be at least 1-D")
    n_sections = sos.shape[0]
    zi_shape = list(x.shape)
    zi_shape[axis] = 2
    zi_shape = [n_sections] + zi_shape
    if zi is not None:
        z = np.array(zi, dtype=float)           # a copy: the kernel updates it in place
        if z.shape != tuple(zi_shape):
            raise ValueError(f"sosfilt: zi has shape {z.shape}; with axis={axis}, x of "
                             f"shape {x.shape} and {n_sections} section(s) it must be "
                             f"{tuple(zi_shape)}")
    else:
        z = np.zeros(zi_shape)
    axis = axis % x.ndim
    x = np.moveaxis(x, axis, -1)
    z = np.moveaxis(z, (0, axis + 1), (-2, -1))
    x_shape, z_shape = x.shape, z.shape
    y = np.array(x.reshape(-1, x.shape[-1]), dtype=float, order="C")   # filtered in place
    z = np.ascontiguousarray(z.reshape(-1, n_sections, 2))
    kernel(np.ascontiguousarray(sos), y, z)
    y = np.moveaxis(y.reshape(x_shape), -1, axis)
    if zi is None:
        return y
    return y, np.moveaxis(z.reshape(z_shape), (-2, -1), (0, axis + 1))


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

    ``scipy.signal.lfilter(b, a, x, zi=scipy.signal.lfiltic(b, a, y_past, x_past))``
    (bit-identical through :func:`lfilter`; to rounding in the numpy fallback): ``y[k] = sum_j b_j x[k-j] - sum_{j>=1} a_j y[k-j]`` with
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
    b, a = _coefficients(b, a)
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    if x.size == 0:
        return np.zeros(0)
    if kernel_available():
        # the one filter path: lfilter from lfiltic's states, as the simulator ran it on
        # scipy.signal (bit-identical to scipy.signal.lfilter(b, a, x, zi=lfiltic(...)))
        zi = lfiltic(b, a, np.zeros(0) if y_past is None else y_past, x_past)
        return lfilter(b, a, x, zi=zi)[0] if zi.size else lfilter(b, a, x)
    return _history_numpy(b, a, x, x_past, y_past)


def _history_numpy(b, a, x, x_past, y_past) -> np.ndarray:
    """:func:`lfilter_history` in numpy (the fallback when scipy's kernel cannot be
    loaded): FIR by convolution, the all-pole part in blocks carried as differences."""
    b, a = b / a[0], a / a[0]
    M, N, T = b.size - 1, a.size - 1, x.size
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
