"""Discrete-time filters with carried state, for chunk-by-chunk simulation.

The stimulator holds each envelope sample for one sample period, so the input of the
participant's dynamics is a staircase: zero-order-hold discretisation is exact for it.
Each filter keeps its state between chunks (so a trial simulated in 100 ms chunks equals
the same trial in one block) and its recent input / output history, so that when its
coefficients change (a new sE) the difference equation continues from the physical
history instead of restarting.

The helpers come from the lowest layer (:mod:`nmsid.protocols.lti_kernels`): public
``scipy.signal.cont2discrete`` and ``scipy.signal.lfilter`` started by ``lfiltic`` from the
past inputs and outputs (tests/protocols/test_lti_kernels.py).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from nmsid.protocols.lti_kernels import cont2discrete_zoh, lfilter_history


@lru_cache(maxsize=4096)
def second_order_zoh(wn_rad_s: float, zeta: float, fs_Hz: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """ZOH discretisation of ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` (unity DC gain).

    Returns
    -------
    b, a : ndarray
        Numerator and denominator of the discrete transfer function (``a[0] == 1``).
    """
    num = [wn_rad_s ** 2]
    den = [1.0, 2.0 * zeta * wn_rad_s, wn_rad_s ** 2]
    b, a = cont2discrete_zoh(num, den, 1.0 / fs_Hz)
    b = np.atleast_1d(np.squeeze(b)).astype(float)
    a = np.asarray(a, dtype=float)
    b = b / a[0]
    a = a / a[0]
    b.setflags(write=False)
    a.setflags(write=False)
    return b, a


@lru_cache(maxsize=4096)
def dynamics_zoh(wn_rad_s: float, zeta: float, tau_s: float, fs_Hz: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """ZOH discretisation of the muscle path: second order, with an extra first-order
    activation lag ``1 / (tau s + 1)`` in cascade when ``tau_s > 0``.

    The cascade is discretised as one system (the lag's output is continuous, not held),
    so it is exact for the stimulator's staircase input.
    """
    if tau_s <= 0:
        return second_order_zoh(wn_rad_s, zeta, fs_Hz)
    num = [wn_rad_s ** 2]
    den = np.polymul([tau_s, 1.0], [1.0, 2.0 * zeta * wn_rad_s, wn_rad_s ** 2])
    b, a = cont2discrete_zoh(num, den, 1.0 / fs_Hz)
    b = np.atleast_1d(np.squeeze(b)).astype(float)
    a = np.asarray(a, dtype=float)
    b, a = b / a[0], a / a[0]
    b.setflags(write=False)
    a.setflags(write=False)
    return b, a


class StatefulFilter:
    """``lfilter`` with state carried across calls and across coefficient changes.

    The state is the recent input / output history (most recent first): the difference
    equation continues from it, with the same coefficients or new ones.
    """

    def __init__(self, order: int = 2):
        self.order = order
        self._b: np.ndarray | None = None
        self._a: np.ndarray | None = None
        self._x_hist = np.zeros(order)   # most recent first
        self._y_hist = np.zeros(order)

    def set_coefficients(self, b: np.ndarray, a: np.ndarray) -> None:
        if self._b is not None and self._a is not None and np.array_equal(b, self._b) \
                and np.array_equal(a, self._a):
            return
        n = max(len(a), len(b)) - 1
        if n != self.order:
            raise ValueError(f"filter order {n} differs from the state's order {self.order}")
        self._b, self._a = b, a

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self._b is None or self._a is None:
            raise RuntimeError("set_coefficients() before filtering")
        if x.size == 0:
            return x.copy()
        y = lfilter_history(self._b, self._a, x, self._x_hist, self._y_hist)
        k = self.order
        if x.size >= k:
            self._x_hist = x[-1:-k - 1:-1].copy()
            self._y_hist = y[-1:-k - 1:-1].copy()
        else:
            self._x_hist = np.concatenate([x[::-1], self._x_hist])[:k]
            self._y_hist = np.concatenate([y[::-1], self._y_hist])[:k]
        return y

    def state(self) -> tuple:
        """Everything needed to continue exactly from here (see :meth:`restore`)."""
        return (self._b, self._a, self._x_hist.copy(), self._y_hist.copy())

    def restore(self, state: tuple) -> None:
        self._b, self._a, xh, yh = state
        self._x_hist, self._y_hist = xh.copy(), yh.copy()

    def reset(self) -> None:
        self._x_hist[:] = 0.0
        self._y_hist[:] = 0.0


class DelayLine:
    """A pure delay of ``delay_samples`` (fractional: linear interpolation), with memory."""

    def __init__(self, delay_samples: float):
        if delay_samples < 0:
            raise ValueError(f"delay must be >= 0 samples, got {delay_samples}")
        self.delay = float(delay_samples)
        self._d = int(np.floor(self.delay))
        self._frac = self.delay - self._d
        self._mem = np.zeros(self._d + 1)   # the last d+1 inputs, oldest first

    def state(self) -> np.ndarray:
        return self._mem.copy()

    def restore(self, state: np.ndarray) -> None:
        self._mem = state.copy()

    def __call__(self, x: np.ndarray) -> np.ndarray:
        m = self._mem.size
        buf = np.concatenate([self._mem, x])
        n = x.size
        # output k = (1-frac) x[k-d] + frac x[k-d-1]; x[j] = buf[j + m]
        k = np.arange(n)
        y = (1.0 - self._frac) * buf[k - self._d + m]
        if self._frac:
            y = y + self._frac * buf[k - self._d - 1 + m]
        self._mem = buf[-m:].copy()
        return y
