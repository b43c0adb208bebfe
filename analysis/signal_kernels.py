"""The few scipy.signal / scipy.ndimage routines identification uses, in numpy alone.

``import scipy.signal`` costs 0.5-0.8 s on the lab PC (scipy 1.17 wraps and re-documents
every function at import), more than the whole identification of a session. These
drop-in versions keep scipy's signatures and conventions for the cases nmsid uses, so a
module swaps its import line and nothing else:

* :func:`lfilter` (transposed direct form II, ``zi``/``zf`` as scipy's), :func:`sosfilt`,
  :func:`sosfilt_zi`, :func:`sosfiltfilt` (odd padding, as scipy's default);
* :func:`butter` (low-pass, digital, ``output="sos"``);
* :func:`savgol_coeffs` (``use="conv"``, any derivative) and :func:`convolve1d`
  (``mode="constant"``);
* :func:`expm` (``scipy.linalg.expm`` for the few-state matrices of a hold
  discretisation: ``import scipy.linalg`` alone costs 0.17 s).

This is the analysis's one filter path, and the product's: every recursion runs on
:func:`nmsid.protocols.lti_kernels.lfilter`, ``scipy.signal``'s own compiled kernel loaded
without ``import scipy.signal`` (bit-identical to ``scipy.signal.lfilter``; ~2-3x faster
than the numpy scan below), the one the gap fits and the simulator use too. :func:`sosfilt`
runs the sections through it one after the other, with their states, as scipy's does.

When the kernel cannot be loaded (another scipy layout), the same functions fall back to a
numpy block scan: the recursion runs block-wise in state space (Blelloch-style,
vectorised): inside a block of ``L`` samples the response is a Toeplitz product; block
start states follow from a log-depth scan of ``s[k+1] = A^L s[k] + f[k]``. It equals the
sample-by-sample recursion up to rounding for well-separated poles (tests compare with
scipy), but loses digits when poles crowd near ``z = 1`` (4 % on a slow 3rd-order filter
at 2 kHz): the fallback keeps the product running, not its best accuracy.
"""

from __future__ import annotations

import functools
import math
import os
import threading

import numpy as np

from nmsid.protocols import lti_kernels as _lti
# one expm for the analysis and the simulator, in the lowest layer (re-exported here)
from nmsid.protocols.lti_kernels import expm  # noqa: F401

__all__ = ["lfilter", "lfilter_zi", "sosfilt", "sosfilt_zi", "sosfiltfilt", "butter",
           "savgol_coeffs", "convolve1d"]

_BLOCK = 16                     # samples per block: fastest on the lab PC for 2k-20k samples


def _state_space(b, a):
    """DF2T state space of b/a: (A, B, D) with y = s[0] + D x, s' = A s + B x."""
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.ndim != 1 or b.ndim != 1 or a.size == 0 or b.size == 0:
        raise ValueError("b and a must be non-empty 1-D coefficient arrays")
    if a[0] == 0:
        raise ValueError("a[0] must not be 0")
    b, a = b / a[0], a / a[0]
    n = max(a.size, b.size) - 1
    b = np.concatenate([b, np.zeros(n + 1 - b.size)])
    a = np.concatenate([a, np.zeros(n + 1 - a.size)])
    A = np.zeros((n, n))
    if n == 0:
        return A, np.zeros(0), float(b[0])
    A[:, 0] = -a[1:]
    A[np.arange(n - 1), np.arange(1, n)] = 1.0
    B = b[1:] - a[1:] * b[0]
    return A, B, float(b[0])


def _powers(A, count):
    """A^0 ... A^(count-1), stacked."""
    n = A.shape[0]
    out = np.empty((count, n, n))
    out[0] = np.eye(n)
    if count > 1:
        out[1] = A
    m = 1                # out[:m + 1] filled: A^(m + j) = A^j A^m for a stack of j at once
    while m + 1 < count:
        hi = min(2 * m, count - 1)
        out[m + 1:hi + 1] = out[1:hi - m + 1] @ out[m]
        m = hi
    return out


@functools.lru_cache(maxsize=8)
def _toeplitz_index(L: int) -> tuple[np.ndarray, np.ndarray]:
    """(causal mask, clipped lag) of an L x L block's Toeplitz matrix (read-only: cached)."""
    idx = np.arange(L)[None, :] - np.arange(L)[:, None]
    causal, clipped = idx >= 0, np.clip(idx, 0, L - 1)
    causal.flags.writeable = clipped.flags.writeable = False
    return causal, clipped


def _run(A, B, D, x, s0, C=None):
    """Filter x (..., N) from states s0 (..., n); returns (y, final states).

    The output is ``y = C s + D x`` (``C`` default: the first state, DF2T's output)."""
    n = A.shape[0]
    N = x.shape[-1]
    lead = x.shape[:-1]
    x = x.reshape(-1, N)                            # rows x samples
    s0 = s0.reshape(-1, n)
    R = x.shape[0]
    L = max(1, min(_BLOCK, N))
    P = _powers(A, L + 1)                           # A^0 .. A^L
    CP = P[:L, 0, :] if C is None else C @ P[:L]    # (L, n): C A^i
    h = np.concatenate([[D], CP[:L - 1] @ B])       # impulse response, first L samples
    causal, clipped = _toeplitz_index(L)
    TT = np.where(causal, h[clipped], 0.0)          # y_block = x_block @ TT
    G = P[L - 1::-1] @ B                            # (L, n): A^(L-1-j) B
    OT = np.ascontiguousarray(CP.T)                 # (n, L): C A^i
    K, r = divmod(N, L)
    y = np.empty((R, N))
    s = s0
    if K:
        xb = x[:, :K * L].reshape(R * K, L)
        yb = xb @ TT
        f = (xb @ G).reshape(R, K, n)               # forced end state of each block
        f[:, 0, :] += s0 @ P[L].T
        # inclusive scan of e[k] = M e[k-1] + f[k], M = A^L (Hillis-Steele, log2 K steps)
        e = f
        M = P[L]
        d = 1
        while d < K:   # in place: the product is formed from the old e before the sum
            e[:, d:, :] += e[:, :-d, :] @ M.T
            M = M @ M
            d *= 2
        starts = np.concatenate([s0[:, None, :], e[:, :-1, :]], axis=1)
        yb += starts.reshape(R * K, n) @ OT
        y[:, :K * L] = yb.reshape(R, K * L)
        s = e[:, -1, :]
    if r:
        xr = x[:, K * L:]
        y[:, K * L:] = xr @ TT[:r, :r] + s @ OT[:, :r]
        s = s @ P[r].T + xr @ (P[r - 1::-1] @ B)
    return y.reshape(lead + (N,)), s.reshape(lead + (n,))


def _moved(x, axis):
    x = np.asarray(x, dtype=float)
    # the filters run along the last axis: most calls pass it already, and np.moveaxis
    # costs ~10 us a call, a tenth of a short filter's time (identification's fits)
    return x if axis in (-1, x.ndim - 1) else np.moveaxis(x, axis, -1)


def _back(y, axis):
    """``np.moveaxis(y, -1, axis)``, skipped when ``axis`` is the last one."""
    return y if axis in (-1, y.ndim - 1) else np.moveaxis(y, -1, axis)


def lfilter(b, a, x, axis: int = -1, zi=None):
    """``scipy.signal.lfilter`` for real float data: the compiled kernel
    (:func:`nmsid.protocols.lti_kernels.lfilter`), or the numpy block scan when it cannot
    be loaded.

    Parameters
    ----------
    b, a : array_like
        Numerator and denominator coefficients (``a[0] != 0``).
    x : array_like
        Input, filtered along ``axis``.
    axis : int
    zi : array_like, optional
        Initial DF2T states, shape of x with ``axis`` of length ``max(len(a), len(b)) - 1``.

    Returns
    -------
    y : ndarray
        Output, same shape as x. With ``zi``: ``(y, zf)``.

    Examples
    --------
    >>> import numpy as np
    >>> y = lfilter([0.5], [1.0, -0.5], np.ones(6))   # 1st-order low-pass, unit DC gain
    >>> np.round(y, 4).tolist()
    [0.5, 0.75, 0.875, 0.9375, 0.9688, 0.9844]
    """
    if _lti.kernel_available():
        return _lti.lfilter(b, a, x, axis=axis, zi=zi)
    A, B, D = _state_space(b, a)
    xm = _moved(x, axis)
    n = A.shape[0]
    if n == 0:
        y = D * xm
        return (_back(y, axis), np.empty(0)) if zi is not None \
            else _back(y, axis)
    if zi is None:
        s0 = np.zeros(xm.shape[:-1] + (n,))
    else:
        s0 = _moved(zi, axis)
        if s0.shape != xm.shape[:-1] + (n,):
            raise ValueError(f"zi has shape {np.shape(zi)}; expected x's shape with axis "
                             f"{axis} of length {n}")
    y, s = _run(A, B, D, xm, s0)
    y = _back(y, axis)
    return (y, _back(s, axis)) if zi is not None else y


def lfilter_zi(b, a) -> np.ndarray:
    """Initial states for a step response in steady state (``scipy.signal.lfilter_zi``)."""
    A, B, _ = _state_space(b, a)
    return np.linalg.solve(np.eye(A.shape[0]) - A, B)


def _check_sos(sos) -> np.ndarray:
    sos = np.atleast_2d(np.asarray(sos, dtype=float))
    if sos.ndim != 2 or sos.shape[1] != 6:
        raise ValueError(f"sos must have shape (n_sections, 6), got {sos.shape}")
    return sos


@functools.lru_cache(maxsize=32)
def _cascade(sos_key: bytes, n_sections: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                      float]:
    """One state space (A, B, C, D) of the whole cascade of second-order sections.

    The states are the sections' DF2T states one after the other; section ``i`` is driven
    by section ``i - 1``'s output ``C_i s_i + D_i u_i``, so ``A`` is block lower-triangular.
    The same recursion as filtering section by section, run in one pass over the data
    (half the memory traffic of two passes for a 4th-order Butterworth). Cached (read-only):
    the identification and its QC filter with a few fixed designs hundreds of times.
    """
    sos = np.frombuffer(sos_key, dtype=float).reshape(n_sections, 6)
    m = 2 * n_sections
    A = np.zeros((m, m))
    B = np.zeros(m)
    C = np.zeros(m)        # output row of the cascade so far, over all states
    D = 1.0
    for i, sec in enumerate(sos):
        Ai, Bi, Di = _state_space(sec[:3], sec[3:])
        j = slice(2 * i, 2 * i + 2)
        # this section's input is the cascade so far: u_i = C s + D x
        A[j, j] = Ai
        A[j, :2 * i] = np.outer(Bi, C[:2 * i])
        B[j] = Bi * D
        C = Di * C
        C[2 * i] = 1.0
        D = Di * D
    for arr in (A, B, C):
        arr.flags.writeable = False
    return A, B, C, D


def _zi_shape(n_sections: int, x_shape: tuple, axis: int) -> tuple:
    """The shape of :func:`sosfilt`'s ``zi`` (``(n_sections,)`` + x's with 2 at ``axis``)."""
    shape = list(x_shape)
    if shape:
        shape[axis] = 2
    return (n_sections, *shape)


def sosfilt(sos, x, axis: int = -1, zi=None):
    """``scipy.signal.sosfilt``: cascaded second-order sections.

    ``zi`` has shape ``(n_sections, ..., 2, ...)`` (the ``2`` at ``axis``) as in scipy;
    with ``zi`` the final states are returned too: ``(y, zf)``. Runs scipy's compiled
    ``_sosfilt`` (:func:`nmsid.protocols.lti_kernels.sosfilt`: bit-identical to
    ``scipy.signal.sosfilt``); sections whose ``a0`` is not 1, or a ``zi`` that only
    broadcasts to its shape, run one after the other through the compiled ``lfilter``
    instead; in the numpy fallback, as one state space (:func:`_cascade`): one pass over
    the data.
    """
    sos = _check_sos(sos)
    k = sos.shape[0]
    if _lti.sos_kernel_available() and np.all(sos[:, 3] == 1) and (
            zi is None or np.shape(zi) == _zi_shape(k, np.shape(x), axis)):
        return _lti.sosfilt(sos, x, axis=axis, zi=zi)   # scipy.signal.sosfilt, bit for bit
    if _lti.kernel_available():   # a0 != 1 or a broadcast zi: the sections one by one
        y = np.asarray(x, dtype=float)
        if zi is None:
            for sec in sos:
                y = _lti.lfilter(sec[:3], sec[3:], y, axis=axis)
            return y
        z = np.asarray(zi, dtype=float)
        if z.shape[0] != k:
            raise ValueError(f"zi has {z.shape[0]} sections; sos has {k}")
        zf = []
        for sec, z_sec in zip(sos, z):
            y, z_out = _lti.lfilter(sec[:3], sec[3:], y, axis=axis, zi=z_sec)
            zf.append(z_out)
        return y, np.stack(zf)
    y = _moved(x, axis)
    A, B, C, D = _cascade(np.ascontiguousarray(sos).tobytes(), k)
    if zi is None:
        s0 = np.zeros(y.shape[:-1] + (2 * k,))
    else:
        z = np.asarray(zi, dtype=float)
        s0 = np.concatenate([np.broadcast_to(_moved(z[i], axis), y.shape[:-1] + (2,))
                             for i in range(k)], axis=-1)
    y, s = _run(A, B, D, y, s0, C)
    y = _back(y, axis)
    if zi is None:
        return y
    return y, np.stack([_back(s[..., 2 * i:2 * i + 2], axis) for i in range(k)])


def sosfilt_zi(sos) -> np.ndarray:
    """Steady-state step initial states of each section (``scipy.signal.sosfilt_zi``)."""
    sos = _check_sos(sos)
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for i, sec in enumerate(sos):
        zi[i] = scale * lfilter_zi(sec[:3], sec[3:])
        scale *= sec[:3].sum() / sec[3:].sum()
    return zi


def sosfiltfilt(sos, x, axis: int = -1, padlen: int | None = None):
    """Forward-backward (zero-phase) filtering with odd padding (``scipy.signal.sosfiltfilt``,
    ``padtype="odd"``).

    With scipy's compiled ``_sosfilt`` (:func:`_sosfiltfilt_rows`): bit-identical to
    ``scipy.signal.sosfiltfilt`` on the same sections, with fewer copies of the data;
    else the sections through :func:`sosfilt` forward and backward."""
    sos = _check_sos(sos)
    xm = _moved(x, axis)
    if padlen is None:
        n_taps = 2 * sos.shape[0] + 1 - min(int(np.sum(sos[:, 2] == 0)),
                                            int(np.sum(sos[:, 5] == 0)))
        padlen = 3 * n_taps
    if padlen >= xm.shape[-1]:
        raise ValueError(f"x has {xm.shape[-1]} samples along axis {axis}; it must have "
                         f"more than padlen = {padlen}")
    if _lti.sos_kernel_available() and np.all(sos[:, 3] == 1):
        return _back(_sosfiltfilt_rows(sos, xm, padlen), axis)
    if padlen > 0:
        first, last = xm[..., :1], xm[..., -1:]
        ext = np.concatenate([2 * first - xm[..., padlen:0:-1], xm,
                              2 * last - xm[..., -2:-padlen - 2:-1]], axis=-1)
    else:
        ext = xm
    zi = sosfilt_zi(sos)                            # (n_sections, 2)
    zi = zi.reshape((zi.shape[0],) + (1,) * (ext.ndim - 1) + (2,))
    y, _ = sosfilt(sos, ext, zi=zi * ext[None, ..., :1])
    y, _ = sosfilt(sos, y[..., ::-1], zi=zi * y[None, ..., -1:])
    y = y[..., ::-1]
    if padlen > 0:
        y = y[..., padlen:-padlen]
    return _back(np.ascontiguousarray(y), axis)


#: A zero-phase filter of at least this many samples (all rows together) splits its rows
#: between the cores (:func:`_sosfiltfilt_rows`): the 45 trials x 30000 samples of a
#: session are 1.35 million; below ~0.2 million a thread costs about what it saves.
PARALLEL_MIN_SAMPLES = 200_000
#: At most this many threads per zero-phase filter (the cores there are, up to it).
MAX_FILTER_THREADS = 4


def filter_threads(n_rows: int, n_samples: int) -> int:
    """How many threads :func:`sosfiltfilt` uses for ``n_rows`` rows of ``n_samples``:
    one below :data:`PARALLEL_MIN_SAMPLES` samples in all, else one per core (at most
    :data:`MAX_FILTER_THREADS`, at most one per row).

    The rows are independent and each is filtered by the same arithmetic in any thread,
    so the result is bit-identical whatever the count; scipy's compiled ``_sosfilt``
    releases the GIL, so the threads run at once.
    """
    if n_rows < 2 or n_rows * n_samples < PARALLEL_MIN_SAMPLES:
        return 1
    return max(1, min(os.cpu_count() or 1, MAX_FILTER_THREADS, n_rows))


def _sosfiltfilt_rows(sos: np.ndarray, xm: np.ndarray, padlen: int) -> np.ndarray:
    """:func:`_sosfiltfilt_block` on the rows of ``xm``, split between
    :func:`filter_threads` threads (the calling thread takes the first share)."""
    lead, n = xm.shape[:-1], xm.shape[-1]
    rows = xm.reshape(-1, n)
    k = filter_threads(rows.shape[0], n)
    if k == 1:
        return _sosfiltfilt_block(sos, rows, padlen).reshape(lead + (n,))
    edges = np.linspace(0, rows.shape[0], k + 1).round().astype(int)
    out = np.empty((rows.shape[0], n))
    errors: list[BaseException] = []

    def share(i: int) -> None:
        try:
            _sosfiltfilt_block(sos, rows[edges[i]:edges[i + 1]], padlen,
                               out=out[edges[i]:edges[i + 1]])
        except BaseException as exc:          # raised again in the calling thread
            errors.append(exc)

    helpers = [threading.Thread(target=share, args=(i,), daemon=True,
                                name="nmsid-sosfiltfilt") for i in range(1, k)]
    for t in helpers:
        t.start()
    share(0)
    for t in helpers:
        t.join()
    if errors:
        raise errors[0]
    return out.reshape(lead + (n,))


def _sosfiltfilt_block(sos: np.ndarray, rows: np.ndarray, padlen: int,
                       out: np.ndarray | None = None) -> np.ndarray:
    """:func:`sosfiltfilt` along the last axis of 2-d ``rows`` with scipy's compiled
    ``_sosfilt``, in place (the result into ``out`` when given, else a new array).

    ``scipy.signal.sosfiltfilt``'s arithmetic step for step (odd extension ``2 x0 -
    x[k]``, states ``sosfilt_zi * x0`` and ``* y[-1]``, the same kernel forward, then on the
    reversed output), but the padded rows are built once in a C-ordered array the kernel
    filters where it is, and the backward pass runs on one reversed copy: three passes over
    the data's memory instead of scipy's five (a 45 x 30000 batch: ~40 % less time).
    """
    n = rows.shape[-1]
    m = n + 2 * padlen
    ext = np.empty((rows.shape[0], m))
    if padlen > 0:                                  # scipy's odd_ext, the same operations
        np.subtract(2 * rows[:, :1], rows[:, padlen:0:-1], out=ext[:, :padlen])
        ext[:, padlen:padlen + n] = rows
        np.subtract(2 * rows[:, -1:], rows[:, -2:-padlen - 2:-1], out=ext[:, padlen + n:])
    else:
        ext[:] = rows
    sos = np.ascontiguousarray(sos)
    zi = sosfilt_zi(sos)                            # (n_sections, 2)
    z = zi[None, :, :] * ext[:, :1, None]           # (rows, n_sections, 2): zi * x0
    _lti.sosfilt_rows_inplace(sos, ext, z)
    back = np.ascontiguousarray(ext[:, ::-1])
    z = zi[None, :, :] * back[:, :1, None]          # zi * y[-1]
    _lti.sosfilt_rows_inplace(sos, back, z)
    y = back[:, m - padlen - 1:padlen - 1 if padlen else None:-1]
    if out is None:
        return np.ascontiguousarray(y)
    out[...] = y
    return out


def butter(N: int, Wn: float, btype: str = "low", analog: bool = False,
           output: str = "sos", fs: float | None = None) -> np.ndarray:
    """Digital Butterworth low-pass as second-order sections (``scipy.signal.butter``
    with ``btype="low", output="sos"``).

    Parameters
    ----------
    N : int
        Order (>= 1).
    Wn : float
        Cut-off (-3 dB): in Hz if ``fs`` is given, else as a fraction of Nyquist.
    fs : float, optional
        Sampling rate in Hz.

    Raises
    ------
    ValueError
        For another band type, an analog design, another output or a cut-off outside
        (0, Nyquist).
    """
    if btype not in ("low", "lowpass") or analog or output != "sos":
        raise ValueError("only the digital low-pass with output='sos' is implemented here; "
                         "use scipy.signal.butter for other designs")
    if int(N) != N or N < 1:
        raise ValueError(f"order N = {N!r} must be an integer >= 1")
    N = int(N)
    wn = 2.0 * Wn / fs if fs is not None else float(Wn)
    if not 0 < wn < 1:
        raise ValueError(f"cut-off {Wn!r} must lie strictly between 0 and Nyquist")
    warped = 4.0 * math.tan(math.pi * wn / 2.0)     # pre-warp (bilinear, fs = 2)
    p_analog = warped * -np.exp(1j * np.pi * np.arange(-N + 1, N, 2) / (2 * N))
    p = (4.0 + p_analog) / (4.0 - p_analog)
    k = float(np.real(warped ** N / np.prod(4.0 - p_analog)))
    # one section per conjugate pair (upper half), one first-order section for a real pole;
    # all zeros at z = -1; poles nearest the unit circle last (as scipy's "nearest")
    pairs = [q for q in p if q.imag > 1e-12]
    reals = [q.real for q in p if abs(q.imag) <= 1e-12]
    sections = []
    for q in reals:
        sections.append((abs(q), [1.0, 1.0, 0.0, 1.0, -q, 0.0]))
    for q in pairs:
        sections.append((abs(q), [1.0, 2.0, 1.0, 1.0, -2.0 * q.real, abs(q) ** 2]))
    sections.sort(key=lambda t: t[0])
    sos = np.array([s for _, s in sections])
    sos[0, :3] *= k
    return sos


def savgol_coeffs(window_length: int, polyorder: int, deriv: int = 0,
                  delta: float = 1.0) -> np.ndarray:
    """Savitzky-Golay convolution taps (``scipy.signal.savgol_coeffs``, ``use="conv"``,
    centred)."""
    if polyorder >= window_length:
        raise ValueError(f"polyorder {polyorder} must be less than window_length "
                         f"{window_length}")
    half, rem = divmod(window_length, 2)
    pos = half - 0.5 if rem == 0 else half
    x = np.arange(-pos, window_length - pos, dtype=float)[::-1]
    A = x[None, :] ** np.arange(polyorder + 1)[:, None]
    rhs = np.zeros(polyorder + 1)
    if deriv <= polyorder:
        rhs[deriv] = math.factorial(deriv) / delta ** deriv
    coeffs, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    return coeffs


def convolve1d(input, weights, axis: int = -1, mode: str = "constant",
               cval: float = 0.0) -> np.ndarray:
    """``scipy.ndimage.convolve1d`` with ``mode="constant"`` (origin 0)."""
    if mode != "constant":
        raise ValueError(f"mode {mode!r}: only 'constant' is implemented here")
    w = np.asarray(weights, dtype=float)
    xm = _moved(input, axis)
    m, n = w.size, xm.shape[-1]
    # ndimage centres the kernel at m // 2 (correlation with reversed taps; an even kernel
    # is shifted by one): output[i] = sum_j w[j] x[i + c - j], c = m // 2 (odd),
    # (m - 1) // 2 (even)
    c = m // 2 if m % 2 else m // 2 - 1
    pad_lo, pad_hi = m - 1 - c, c
    ext = np.concatenate([np.full(xm.shape[:-1] + (pad_hi,), cval), xm,
                          np.full(xm.shape[:-1] + (pad_lo,), cval)], axis=-1)
    rows = ext.reshape(-1, ext.shape[-1])
    out = np.stack([np.convolve(r, w, mode="valid") for r in rows]) if rows.size else rows
    return _back(out.reshape(xm.shape[:-1] + (n,)), axis)

