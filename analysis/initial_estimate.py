"""Starting values for the output-error fit: simplified refined instrumental variables.

The sampled second-order model with offset, ramp and unknown initial state obeys, exactly,
for k >= 2 the difference equation

    y_k + d1 y_(k-1) + d2 y_(k-2) = n0 v_k + n1 v_(k-1) + n2 v_(k-2) + e0 + e1 tau_k

(the initial state only sets y_0, y_1; offset and ramp pass through D as another offset
and ramp). An ordinary least-squares fit of it is biased by noise; the Steiglitz-McBride /
SRIV iteration (Young 2011, "Recursive Estimation and Time-Series Analysis", ch. 7;
MATLAB's tfest initialises with the continuous-time version, SRIVC) removes the bias by
pre-filtering every column with 1/D of the previous estimate and using the noise-free
simulated output as instrument for the output lags. The converged discrete poles are
mapped to continuous time (s = ln z / dt) to give wn and zeta; Kp is the static gain.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from nmsid.analysis.thin_lstsq import cross, lstsq_rows

logger = logging.getLogger(__name__)


@dataclass
class StartEstimate:
    """Continuous-time starting values and how they were obtained."""

    Kp: float
    wn_rad_s: float
    zeta: float
    iterations: int
    method: str


def _lagged(x: np.ndarray, lag: int) -> np.ndarray:
    out = np.zeros_like(x)
    out[lag:] = x[:len(x) - lag] if lag else x
    return out


def _regressors(y: np.ndarray, v: np.ndarray, tau: np.ndarray, trend: bool) -> np.ndarray:
    rows = [-_lagged(y, 1), -_lagged(y, 2), v, _lagged(v, 1), _lagged(v, 2),
            np.ones_like(v)] + ([tau] if trend else [])
    phi = np.vstack(rows)
    phi[:, :2] = 0.0            # the equation holds from k = 2 on
    return phi


def poles_to_continuous(den: np.ndarray, dt_s: float) -> tuple[float, float] | None:
    """(wn, zeta) of the continuous second-order system whose sampled poles are the roots
    of ``z^2 + den[1] z + den[2]``; None if they are not those of a stable such system."""
    b, c = float(den[1]), float(den[2])
    disc = b * b / 4 - c
    if not (math.isfinite(b) and math.isfinite(c)):
        return None
    if disc < 0:                                     # complex pair
        mod = math.sqrt(c)
        if mod >= 1.0 or mod == 0.0:
            return None
        angle = math.atan2(math.sqrt(-disc), -b / 2)
        sigma = -math.log(mod) / dt_s
        wd = angle / dt_s
        wn = math.hypot(sigma, wd)
        zeta = sigma / wn
    else:                                            # two real poles
        r1 = -b / 2 + math.sqrt(disc)
        r2 = -b / 2 - math.sqrt(disc)
        if not (0 < r2 <= r1 < 1):
            return None
        s1, s2 = math.log(r1) / dt_s, math.log(r2) / dt_s
        wn = math.sqrt(s1 * s2)
        zeta = -(s1 + s2) / (2 * wn)
    if not (np.isfinite(wn) and np.isfinite(zeta) and wn > 0 and zeta > 0):
        return None
    return float(wn), float(zeta)


def srivc_start(v: np.ndarray, y: np.ndarray, dt_s: float, *, trend: bool = True,
                iterations: int = 6) -> StartEstimate | None:
    """Steiglitz-McBride instrumental-variable estimate of a second-order model.

    Parameters
    ----------
    v : ndarray
        Input samples (already corrected for the hold, see ``discretize.smooth_hold_input``).
    y : ndarray
        Output samples (same length).
    dt_s : float
        Sampling interval in s.
    trend : bool
        Include a ramp term (see ``IdentificationSettings.estimate_trend``).
    iterations : int
        Maximum number of pre-filter / IV iterations.

    Returns
    -------
    StartEstimate or None
        None when no stable second-order system fits (the caller then falls back to a
        grid search).
    """
    n = len(y)
    tau = np.linspace(-1.0, 1.0, n)
    phi = _regressors(y, v, tau, trend)
    target = y.copy()
    target[:2] = 0.0
    theta = lstsq_rows(phi, target)[0]
    den = np.array([1.0, theta[0], theta[1]])
    done = 0
    for done in range(1, iterations + 1):  # noqa: B007 (the count is returned)
        if poles_to_continuous(den, dt_s) is None:
            break
        num = theta[2:5]
        x = lfilter(num, den, v)                      # noise-free instrument
        z_rows = _regressors(x, v, tau, trend)
        # regressors, instruments and target through the pre-filter in one call (each
        # row filtered on its own: the same numbers as three calls)
        m = len(phi)
        filtered = lfilter([1.0], den, np.vstack([phi, z_rows, target]), axis=1)
        phi_f, z_f, y_f = filtered[:m], filtered[m:2 * m], filtered[2 * m]
        try:
            new = np.linalg.solve(cross(z_f, phi_f), cross(z_f, y_f[None, :])[:, 0])
        except np.linalg.LinAlgError:
            break
        new_den = np.array([1.0, new[0], new[1]])
        change = np.max(np.abs(new_den - den))
        theta, den = new, new_den
        if change < 1e-9:
            break
    ct = poles_to_continuous(den, dt_s)
    if ct is None:
        logger.debug("SRIV start gave no stable second-order system (den=%s)", den)
        return None
    gain = float(np.sum(theta[2:5]) / np.sum(den))
    if not np.isfinite(gain):
        return None
    return StartEstimate(Kp=gain, wn_rad_s=ct[0], zeta=ct[1], iterations=done, method="sriv")
