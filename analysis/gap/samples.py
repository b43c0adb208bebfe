"""Effective number of independent samples of a correlated residual or noise record.

The force is low-passed at 25 Hz and evaluated at 100 Hz, and a model's misfit is
smooth, so neighbouring samples are far from independent: ``N_eff = N nu``.
"""

from __future__ import annotations

import numpy as np


def effective_fraction(resid: np.ndarray, fs_eval_Hz: float, bandwidth_Hz: float,
                       max_lag: int = 100) -> float:
    """``nu = N_eff / N`` from the mean autocorrelation of residual rows (see module)."""
    r = resid - resid.mean(axis=1, keepdims=True)
    n = r.shape[1]
    lags = min(max_lag, n - 1)
    f = np.fft.rfft(r, 2 * n, axis=1)
    ac = np.fft.irfft(np.abs(f) ** 2, axis=1)[:, :lags + 1].sum(axis=0)
    if ac[0] <= 0:
        return min(1.0, 2 * bandwidth_Hz / fs_eval_Hz)
    rho = ac[1:] / ac[0]
    s = 0.0
    for v in rho:
        if v < 0.05:
            break
        s += v
    return float(min(1.0 / (1.0 + 2.0 * s), 2 * bandwidth_Hz / fs_eval_Hz))
