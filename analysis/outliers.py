"""Quartiles as MATLAB's ``prctile`` computes them, and IQR outlier removal.

MATLAB's ``prctile(x, p)`` (Statistics and Machine Learning Toolbox, default method)
sorts the n values and gives the i-th smallest the percentile ``100 (i - 0.5) / n``;
percentiles in between are interpolated linearly, below the first / above the last the
smallest / largest value is returned. This is numpy's ``method="hazen"``; it is written
out here so that the rule is visible and tested against hand-computed values.

Outliers (paper: "IQR method", Tukey's fences): values below Q1 - k IQR or above
Q3 + k IQR, k = 1.5, IQR = Q3 - Q1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def matlab_prctile(x, p: float) -> float:
    """The p-th percentile of the finite values of x, as MATLAB's ``prctile``.

    Parameters
    ----------
    x : array-like
        Values (NaNs are ignored, as MATLAB's ``prctile`` does).
    p : float
        Percentile in [0, 100].

    Returns
    -------
    float
        NaN if x has no finite value.

    Examples
    --------
    >>> matlab_prctile([1, 2, 3, 4], 25)   # positions 12.5, 37.5, 62.5, 87.5
    1.5
    >>> matlab_prctile([1, 2, 3, 4, 100], 75)  # 4 + (75 - 70) / 20 * (100 - 4)
    28.0
    """
    if not 0 <= p <= 100:
        raise ValueError(f"percentile p = {p!r} must be in [0, 100]")
    v = np.sort(np.asarray(x, dtype=float)[np.isfinite(np.asarray(x, dtype=float))])
    n = len(v)
    if n == 0:
        return float("nan")
    pos = 100.0 * (np.arange(1, n + 1) - 0.5) / n
    if p <= pos[0]:
        return float(v[0])
    if p >= pos[-1]:
        return float(v[-1])
    return float(np.interp(p, pos, v))


@dataclass
class IqrFences:
    """Quartiles and the fences outside which a value is an outlier."""

    q1: float
    q3: float
    k: float

    @property
    def iqr(self) -> float:
        return self.q3 - self.q1

    @property
    def low(self) -> float:
        return self.q1 - self.k * self.iqr

    @property
    def high(self) -> float:
        return self.q3 + self.k * self.iqr


def iqr_fences(x, k: float = 1.5) -> IqrFences:
    """Quartiles (MATLAB ``prctile``) and fences of the finite values of x."""
    return IqrFences(matlab_prctile(x, 25), matlab_prctile(x, 75), float(k))


def iqr_inliers(x, k: float = 1.5) -> np.ndarray:
    """Boolean mask: True for finite values inside [Q1 - k IQR, Q3 + k IQR].

    Examples
    --------
    >>> iqr_inliers([1.0, 2.0, 3.0, 4.0, 100.0]).tolist()
    [True, True, True, True, False]
    """
    arr = np.asarray(x, dtype=float)
    finite = np.isfinite(arr)
    if not finite.any():
        return finite
    f = iqr_fences(arr, k)
    return finite & (arr >= f.low) & (arr <= f.high)
