"""The simulator's two linear time-invariant helpers, on public ``scipy.signal``.

* :func:`cont2discrete_zoh`: ``scipy.signal.cont2discrete((num, den), dt_s,
  method="zoh")``'s numerator and denominator;
* :func:`lfilter_history`: ``scipy.signal.lfilter`` started by ``scipy.signal.lfiltic``
  from the past inputs and outputs, so a difference equation continues from its history
  (a chunk of a trial, or a new sE level with new coefficients).

``scipy.signal`` is imported inside the functions: only a process that simulates pays
its import (about 0.5 s).
"""

from __future__ import annotations

import numpy as np

__all__ = ["cont2discrete_zoh", "lfilter_history"]


def cont2discrete_zoh(num, den, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of ``num(s) / den(s)`` with sample time ``dt_s``.

    Exact for a staircase input (the stimulator holds each sample for one period).

    Returns
    -------
    num_d : ndarray
        Shape ``(1, n + 1)``, as scipy's.
    den_d : ndarray
        Shape ``(n + 1,)``.

    Raises
    ------
    ValueError
        For ``dt_s <= 0``.

    Examples
    --------
    >>> import numpy as np
    >>> b, a = cont2discrete_zoh([1.0], [1.0, 1.0], 0.1)   # 1 / (s + 1)
    >>> np.round(b, 6).tolist(), np.round(a, 6).tolist()
    ([[0.0, 0.095163]], [1.0, -0.904837])
    """
    if not dt_s > 0:
        raise ValueError(f"sample time dt_s = {dt_s!r} must be > 0")
    from scipy.signal import cont2discrete
    num_d, den_d, _ = cont2discrete((num, den), dt_s, method="zoh")
    return np.atleast_2d(num_d), np.asarray(den_d, dtype=float)


def lfilter_history(b, a, x, x_past=None, y_past=None) -> np.ndarray:
    """Filter ``x`` with ``b(z) / a(z)``, continuing from past inputs and outputs:
    ``scipy.signal.lfilter(b, a, x, zi=scipy.signal.lfiltic(b, a, y_past, x_past))``.

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

    Raises
    ------
    ValueError
        For an ``x`` that is not 1-D.

    Examples
    --------
    >>> import numpy as np
    >>> y = lfilter_history([0.5], [1.0, -0.5], np.ones(4), y_past=[1.0])  # at rest at 1
    >>> y.tolist()
    [1.0, 1.0, 1.0, 1.0]
    """
    from scipy.signal import lfilter, lfiltic
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    if x.size == 0:
        return np.zeros(0)
    y0 = np.zeros(0) if y_past is None else np.asarray(y_past, dtype=float).ravel()
    x0 = None if x_past is None else np.asarray(x_past, dtype=float).ravel()
    if max(a.size, b.size) == 1:
        return lfilter(b, a, x)
    zi = lfiltic(b, a, y0, x0)
    return lfilter(b, a, x, zi=zi)[0]
