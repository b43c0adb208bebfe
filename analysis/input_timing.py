"""The rig's input timing: how far the stimulation lags (or leads) the rE record.

A rig turns commanded rE samples into current in its own way: our simulated stimulator
holds each sample for one sample period (a zero-order hold, the input lags the record by
half a sample: 0.25 ms at 2 kHz), a DAC with a reconstruction filter delays it by a
fraction of a millisecond, a record time-stamped after the output leads it. At 10 Hz a
0.25 ms mismatch is a 0.9 degree phase error: invisible in the fit percentage, but on a
quiet sensor it correlates the residual with the input (the ``resid-input corr`` flag) and
the gap diagnosis would fit it as some effect. So the timing is one setting,
``IdentificationSettings.input_timing``, shared by identification and gap diagnosis:
``"estimate"`` (default), ``"hold"``, ``"smooth"`` or a delay calibrated per rig.

Estimate. Around a fitted second-order model ``y = Kp x(t) + ...`` a small delay ``d`` of
the input changes the output by ``-d Kp x'(t)``. With the other parameters free (Kp, wn,
zeta, offset, trend, initial state), the Gauss-Newton step for ``d`` is the least-squares
coefficient of the residual on the part of ``-Kp x'`` that those parameters cannot
absorb; its standard error follows from the fit's equivalent white noise. A session's
estimate pools its levels (inverse-variance weighted) and is clipped to
``+-input_timing_max_s``. It is used only when it differs from zero by more than four
standard errors and 20 us: a rig without a delay is not given a noisy one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from nmsid.analysis.discretize import foh_coefficients, smooth_hold_input
from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.preprocess import LevelData, TrialSignals, preprocess_trials
from nmsid.analysis.second_order import SecondOrderFit, fit_second_order
from nmsid.analysis.settings import IdentificationSettings, InputTiming

#: A delay must exceed this many standard errors to be used (the standard error assumes
#: white noise at the fit rate: a margin against its optimism on low-passed data) ...
SIGNIFICANCE_SE = 4.0

#: ... and this size: below 20 us (1/25 of a sample at 2 kHz) a delay moves the phase at
#: 10 Hz by less than 0.08 degree, nothing the fit or the residual tests can notice.
MIN_DELAY_S = 20e-6


@dataclass(frozen=True)
class TimingEstimate:
    """A delay estimate of the stimulation behind the rE record (s; either sign)."""

    delay_s: float
    se_s: float
    source: str
    """``estimated``, ``estimated (not significant: 0 used)``, ``hold``, ``smooth`` or
    ``calibrated``."""
    n_levels: int = 0

    def as_dict(self) -> dict:
        return {"input_delay_s": self.delay_s, "se_s": self.se_s, "source": self.source,
                "n_levels": self.n_levels}


def _forced(v: np.ndarray, wn: float, zeta: float, dt: float) -> np.ndarray:
    num, den = foh_coefficients(wn, zeta, dt)
    return lfilter(num, den, v)


def delay_step(u: np.ndarray, y_resid: np.ndarray, fit: SecondOrderFit) -> tuple[float, float]:
    """Gauss-Newton step of the input delay around a fit, and its standard error (s).

    Parameters
    ----------
    u : ndarray
        The fitted input (``LevelData.u``).
    y_resid : ndarray
        The fit's residual (``fit.residual_N``).
    fit : SecondOrderFit

    Returns
    -------
    delay_s, se_s : float
        ``nan`` when the delay cannot be told from the other parameters.
    """
    dt = 1.0 / fit.fs_Hz
    v = smooth_hold_input(u)
    wn, z = fit.wn_rad_s, fit.zeta
    x = _forced(v, wn, z, dt)
    eps = 1e-5
    cols = [x,
            (_forced(v, wn * (1 + eps), z, dt) - _forced(v, wn * (1 - eps), z, dt)) / (2 * eps),
            (_forced(v, wn, z * (1 + eps), dt) - _forced(v, wn, z * (1 - eps), dt)) / (2 * eps)]
    num, den = foh_coefficients(wn, z, dt)
    imp = np.zeros(len(u))
    imp[0] = 1.0
    h = lfilter([1.0], den, imp)
    cols += [h, np.concatenate([[0.0], h[:-1]]), np.ones(len(u)), np.linspace(-1, 1, len(u))]
    g = -fit.Kp * np.gradient(x) / dt
    Q, _ = np.linalg.qr(np.column_stack(cols))
    g_perp = g - Q @ (Q.T @ g)
    gg = float(g_perp @ g_perp)
    if not gg > 0 or not math.isfinite(fit.noise_sd_N):
        return float("nan"), float("nan")
    r = y_resid - Q @ (Q.T @ y_resid)
    return float(g_perp @ r) / gg, float(fit.noise_sd_N) / math.sqrt(gg)


def pooled(steps, max_s: float) -> TimingEstimate:
    """Inverse-variance pooling of per-level ``(delay_s, se_s)``; zero unless significant.

    Examples
    --------
    >>> pooled([(2e-4, 1e-5), (3e-4, 1e-5)], 1e-3).delay_s
    0.00025
    >>> pooled([(1e-6, 1e-5)], 1e-3).delay_s
    0.0
    """
    ok = [(d, s) for d, s in steps if math.isfinite(d) and math.isfinite(s) and s > 0]
    if not ok:
        return TimingEstimate(0.0, float("nan"), "estimated (not identifiable: 0 used)", 0)
    w = np.array([1.0 / s ** 2 for _, s in ok])
    d = float(np.sum(w * np.array([d for d, _ in ok])) / np.sum(w))
    se = float(1.0 / math.sqrt(np.sum(w)))
    at_bound = abs(d) >= max_s
    d = float(np.clip(d, -max_s, max_s))
    if abs(d) <= max(SIGNIFICANCE_SE * se, MIN_DELAY_S):
        return TimingEstimate(0.0, se, "estimated (not significant: 0 used)", len(ok))
    return TimingEstimate(round(d, 9), se, "estimated at the bound (the data ask for more: "
                          "physiology, e.g. a dead time, or a rig to calibrate)" if at_bound
                          else "estimated", len(ok))


def fixed_timing(settings: IdentificationSettings, fs_Hz: float) -> TimingEstimate | None:
    """The timing the settings fix (None for ``"estimate"``)."""
    t = settings.input_timing
    if isinstance(t, float):
        return TimingEstimate(t, 0.0, "calibrated")
    if t is InputTiming.HOLD:
        return TimingEstimate(0.5 / fs_Hz, 0.0, "hold")
    if t is InputTiming.SMOOTH:
        return TimingEstimate(0.0, 0.0, "smooth")
    return None


def fit_level(trials, settings: IdentificationSettings | None = None, *,
              cache: TrialSignals | None = None
              ) -> tuple[LevelData, SecondOrderFit, TimingEstimate]:
    """Preprocess and fit one sE level with the input-timing model of the settings.

    With ``input_timing = "estimate"`` the level is fitted without a delay, the delay is
    estimated from that fit, and, when significant, the level is preprocessed again with
    it and refitted (from the first fit's wn, zeta). ``cache``: each repeat filtered once
    for the session's fits (:class:`nmsid.analysis.preprocess.TrialSignals`).

    Raises
    ------
    IdentificationError
        As :func:`nmsid.analysis.preprocess.preprocess_trials` and
        :func:`nmsid.analysis.second_order.fit_second_order`.
    """
    s = settings or IdentificationSettings()
    trials = list(trials)
    if not trials:
        raise IdentificationError("no trials to fit")
    fs = float(trials[0].fs_Hz)
    fixed = fixed_timing(s, fs)
    data = preprocess_trials(trials, s, input_delay_s=fixed.delay_s if fixed else 0.0,
                             cache=cache)
    fit = fit_second_order(data.u, data.y_N, data.fs_Hz, s, band_Hz=data.band_Hz,
                           t0_s=float(data.t_s[0]))
    if fixed is not None:
        return data, fit, fixed
    est = pooled([delay_step(data.u, fit.residual_N, fit)], s.input_timing_max_s)
    if est.delay_s != 0.0:
        data = preprocess_trials(trials, s, input_delay_s=est.delay_s, cache=cache)
        fit = fit_second_order(data.u, data.y_N, data.fs_Hz, s, band_Hz=data.band_Hz,
                               start=(fit.wn_rad_s, fit.zeta), t0_s=float(data.t_s[0]))
    return data, fit, est


def estimate_session_timing(trials, settings: IdentificationSettings | None = None
                            ) -> TimingEstimate:
    """The input timing of a session: fixed by the settings, or estimated from its levels.

    Parameters
    ----------
    trials : sequence of protocols.session_file.Trial
        Completed trials with finite data (several sE levels).
    settings : IdentificationSettings, optional

    Returns
    -------
    TimingEstimate
    """
    s = settings or IdentificationSettings()
    trials = list(trials)
    if not trials:
        return TimingEstimate(0.0, float("nan"), "no trials")
    fixed = fixed_timing(s, float(trials[0].fs_Hz))
    if fixed is not None:
        return fixed
    groups: dict[float, list] = {}
    for t in trials:
        groups.setdefault(round(float(t.sE), 9), []).append(t)
    steps = []
    for key in sorted(groups):
        try:
            data = preprocess_trials(groups[key], s, input_delay_s=0.0)
            fit = fit_second_order(data.u, data.y_N, data.fs_Hz, s, band_Hz=data.band_Hz)
        except (IdentificationError, np.linalg.LinAlgError, ArithmeticError):
            continue
        steps.append(delay_step(data.u, fit.residual_N, fit))
    return pooled(steps, s.input_timing_max_s)
