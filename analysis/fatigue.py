"""Within-session fatigue: the gain lost with accumulated stimulation, with its uncertainty.

FES recruits the same motor units at every pulse, so the force a given stimulation
produces falls through a session (fatigue) or, early on, rises (potentiation). The
session's own structure measures it: the schedule is randomised, so the repeats of one sE
fall at different times, and each trial's gain compared with the other repeats of *its
own* sE tells how the gain moved with the stimulation given before it. Nothing about the
participant's curves over sE is assumed.

Model (one shared rate, one free gain per sE level)::

    ln g_ij = a_j - lambda c_ij + e_ij

``g_ij`` is the gain of trial ``i`` at level ``j`` (the identified per-trial Kp, or a
trial's gain relative to a model), ``c_ij`` the cumulative stimulation time (s) at the
centre of its analysis window, ``a_j`` the level's unfatigued log-gain and ``e_ij`` the
trial-to-trial scatter. It is a linear fixed-effects regression: ``lambda`` is the slope of
the within-level deviations of ``ln g`` on those of ``c``, in closed form, and its standard
error is ``s / sqrt(Sxx)`` with ``s^2`` the residual variance on ``n - L - 1`` degrees of
freedom (``L`` levels with at least two trials). The gain lost over the session is
``1 - exp(-lambda C)`` with ``C`` the session's total stimulation; its confidence interval
maps the Student-t interval of ``lambda`` through the same function. The exponential
shape is that of the classic first-order fatigue models (Riener et al. 1996, Ding et al.
2000) at constant drive; a linear loss of 15-30 % differs from it by at most 1.5
percentage points at the session's end.

The effect is *significant* when ``|lambda|`` exceeds ``z_crit`` standard errors and the
loss (or gain) over the session is at least ``min_effect_pct`` percent.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass

import numpy as np

#: Standard errors a rate must exceed to be called fatigue (or potentiation).
Z_CRIT = 3.0

#: ... and the least gain change over the session worth reporting, percent.
MIN_EFFECT_PCT = 3.0


@dataclass(frozen=True)
class FatigueResult:
    """The gain change over a session with accumulated stimulation.

    Attributes
    ----------
    loss_pct : float
        Gain lost between the session's start and its end (``1 - exp(-lambda C)``), percent
        of the unfatigued gain; negative for potentiation (a gain that grows).
    ci_low_pct, ci_high_pct : float
        Its 95 % confidence interval.
    se_pct : float
        Standard error of ``loss_pct`` (delta method at the estimate).
    rate_per_100s : float
        ``lambda`` times 100 s: the fraction of gain lost per 100 s of stimulation.
    z : float
        ``lambda`` over its standard error.
    significant : bool
        ``|z| >= z_crit`` and ``|loss_pct| >= min_effect_pct``.
    total_stim_s : float
        The session's cumulative stimulation ``C`` the loss refers to, s.
    n_trials, n_levels, dof : int
        Trials and sE levels that carry information (levels with two or more trials);
        residual degrees of freedom.
    residual_sd_pct : float
        Trial-to-trial scatter of the gain left after the trend (SD of ``ln g``), percent.
    source : str
        What the gains are (e.g. ``per-trial Kp``).
    note : str
        Why nothing was estimated, when nothing was.
    """

    loss_pct: float
    ci_low_pct: float
    ci_high_pct: float
    se_pct: float
    rate_per_100s: float
    z: float
    significant: bool
    total_stim_s: float
    n_trials: int
    n_levels: int
    dof: int
    residual_sd_pct: float
    source: str = ""
    note: str = ""

    @property
    def estimated(self) -> bool:
        """True when a rate was estimated (enough repeats spread in time)."""
        return math.isfinite(self.loss_pct)

    def sentence(self) -> str:
        """The result in one line a physiologist reads."""
        if not self.estimated:
            return f"fatigue not estimated: {self.note}"
        what = "lost" if self.loss_pct >= 0 else "gained"
        word = ("fatigue" if self.loss_pct >= 0 else "potentiation") if self.significant \
            else "no significant fatigue"
        return (f"{word}: the gain {what} {abs(self.loss_pct):.1f} % (95 % CI "
                f"{self.ci_low_pct:.1f} to {self.ci_high_pct:.1f} %) over "
                f"{self.total_stim_s:.0f} s of stimulation (z = {self.z:.1f}; "
                f"{self.n_trials} trials at {self.n_levels} sE levels, {self.source}; "
                f"scatter left {self.residual_sd_pct:.1f} %)")

    def as_dict(self) -> dict:
        return asdict(self)


def _bisect(cdf, p: float, lo: float, hi: float) -> float:
    while cdf(hi) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if cdf(mid) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


def t_ppf(p: float, dof: int) -> float:
    """Quantile of Student's t with integer ``dof`` (exact finite series of Abramowitz &
    Stegun 26.7.3-4, inverted by bisection): no scipy.stats, which would load
    scipy.special into every ``nmsid identify`` start.

    Examples
    --------
    >>> round(t_ppf(0.975, 1), 4), round(t_ppf(0.975, 10), 4), round(t_ppf(0.5, 3), 4)
    (12.7062, 2.2281, 0.0)
    """
    if dof < 1:
        raise ValueError(f"dof = {dof}: at least 1")
    return _t_ppf(float(p), int(dof))


@functools.lru_cache(maxsize=256)
def _t_ppf(p: float, n: int) -> float:
    """:func:`t_ppf` once per (p, dof): a session asks for the same few quantiles many
    times (every level's and parameter's interval)."""
    if p == 0.5:
        return 0.0
    if p < 0.5:
        return -_t_ppf(1.0 - p, n)

    def central(t: float) -> float:          # P(|T| < t)
        th = math.atan(t / math.sqrt(n))
        c2 = math.cos(th) ** 2
        if n % 2 == 0:
            term = acc = 1.0
            for k in range(1, (n - 2) // 2 + 1):
                term *= c2 * (2 * k - 1) / (2 * k)
                acc += term
            return math.sin(th) * acc
        if n == 1:
            return 2.0 * th / math.pi
        term = acc = math.cos(th)
        for k in range(1, (n - 3) // 2 + 1):
            term *= c2 * (2 * k) / (2 * k + 1)
            acc += term
        return 2.0 / math.pi * (th + math.sin(th) * acc)

    return _bisect(central, 2.0 * p - 1.0, 0.0, 10.0)


def chi2_ppf(p: float, dof: int) -> float:
    """Quantile of the chi-square distribution with integer ``dof`` (exact finite series,
    inverted by bisection; see :func:`t_ppf` for why not scipy.stats).

    Examples
    --------
    >>> round(chi2_ppf(0.025, 2), 5), round(chi2_ppf(0.975, 30), 3), round(chi2_ppf(0.5, 1), 4)
    (0.05064, 46.979, 0.4549)
    """
    if dof < 1:
        raise ValueError(f"dof = {dof}: at least 1")
    return _chi2_ppf(float(p), int(dof))


@functools.lru_cache(maxsize=256)
def _chi2_ppf(p: float, k: int) -> float:
    """:func:`chi2_ppf` once per (p, dof) (see :func:`_t_ppf`)."""

    def cdf(x: float) -> float:
        if x <= 0:
            return 0.0
        h = 0.5 * x
        if k % 2 == 0:
            term = math.exp(-h)
            acc = term
            for j in range(1, k // 2):
                term *= h / j
                acc += term
            return 1.0 - acc
        q = math.erfc(math.sqrt(h))             # 2 (1 - Phi(sqrt x))
        term = math.sqrt(2.0 * x / math.pi) * math.exp(-h)   # j = 1: x^(1/2) / 1
        acc = 0.0
        for j in range(1, (k - 1) // 2 + 1):
            if j > 1:
                term *= x / (2 * j - 1)
            acc += term
        return 1.0 - q - acc

    return _bisect(cdf, p, 0.0, max(1.0, 2.0 * k))


def _not_estimated(note: str, n: int, total: float, source: str) -> FatigueResult:
    nan = float("nan")
    return FatigueResult(nan, nan, nan, nan, nan, nan, False, total, n, 0, 0, nan, source,
                         note)


def fit_fatigue(gain, level, cum_stim_s, *, total_stim_s: float | None = None,
                z_crit: float = Z_CRIT, min_effect_pct: float = MIN_EFFECT_PCT,
                source: str = "") -> FatigueResult:
    """Fit the shared fatigue rate of a session (see module).

    Parameters
    ----------
    gain : array_like
        Positive gain of each trial (per-trial Kp, or gain relative to a model).
        Non-finite or non-positive entries are left out.
    level : array_like
        The sE level of each trial (any hashable label; equal labels = same level).
    cum_stim_s : array_like
        Cumulative stimulation time at each trial's analysis window, s.
    total_stim_s : float, optional
        The session's total stimulation, the span the loss is reported over (default: the
        largest ``cum_stim_s``).
    z_crit, min_effect_pct : float
        Significance (see module).
    source : str
        What the gains are (printed in the sentence).

    Returns
    -------
    FatigueResult

    Examples
    --------
    >>> import numpy as np
    >>> c = np.array([10., 200, 400, 100, 300, 500])
    >>> g = np.array([5., 5, 5, 8, 8, 8]) * np.exp(-c / 2000)
    >>> r = fit_fatigue(g, [0, 0, 0, 1, 1, 1], c, total_stim_s=600)
    >>> round(r.loss_pct, 2), r.significant
    (25.92, True)
    """
    g = np.asarray(gain, dtype=float)
    c = np.asarray(cum_stim_s, dtype=float)
    lev = np.asarray(level)
    if not (len(g) == len(c) == len(lev)):
        raise ValueError("gain, level and cum_stim_s need one entry per trial")
    ok = np.isfinite(g) & (g > 0) & np.isfinite(c)
    total = float(total_stim_s) if total_stim_s is not None else \
        (float(np.max(c[ok])) if ok.any() else float("nan"))
    y = np.log(g[ok])
    c, lev = c[ok], lev[ok]
    dy, dc = [], []
    n_levels = 0
    for key in dict.fromkeys(lev.tolist()):
        m = lev == key
        if m.sum() < 2:
            continue
        n_levels += 1
        dy.append(y[m] - y[m].mean())
        dc.append(c[m] - c[m].mean())
    n = int(sum(len(v) for v in dy))
    dof = n - n_levels - 1
    if n_levels == 0 or dof < 1:
        return _not_estimated("fewer than two repeats at any sE, or too few trials for a "
                              "trend beside the levels' own gains", n, total, source)
    Y, X = np.concatenate(dy), np.concatenate(dc)
    sxx = float(X @ X)
    if not sxx > 0 or not math.isfinite(total) or total <= 0:
        return _not_estimated("the repeats of each sE fall at the same cumulative "
                              "stimulation: no time contrast", n, total, source)
    slope = float(X @ Y) / sxx                    # d ln g / dc = -lambda
    resid = Y - slope * X
    s2 = float(resid @ resid) / dof
    se = math.sqrt(s2 / sxx)
    lam, t = -slope, t_ppf(0.975, dof)

    def loss(rate: float) -> float:
        return 100.0 * -math.expm1(-rate * total)

    z = lam / se if se > 0 else (math.inf if lam != 0 else 0.0)
    est = loss(lam)
    se_pct = 100.0 * total * math.exp(-lam * total) * se
    significant = bool(abs(z) >= z_crit and abs(est) >= min_effect_pct)
    return FatigueResult(loss_pct=est, ci_low_pct=loss(lam - t * se),
                         ci_high_pct=loss(lam + t * se), se_pct=se_pct,
                         rate_per_100s=100.0 * lam, z=float(z), significant=significant,
                         total_stim_s=total, n_trials=n, n_levels=n_levels, dof=dof,
                         residual_sd_pct=100.0 * math.sqrt(s2), source=source)


def cumulative_stimulation_s(trials) -> tuple[np.ndarray, float]:
    """Cumulative stimulation time at the centre of each trial's analysis window.

    Every trial of the file counts, in the file's order (the order they were run), aborted
    ones included for the samples they hold: a trial stimulates from its first sample (the
    lead-in at rE = 0.5 is stimulation too).

    Parameters
    ----------
    trials : sequence of protocols.session_file.Trial
        All trials of the session, in file order.

    Returns
    -------
    centre_s : (n_trials,) ndarray
        Stimulation given before the trial plus its lead-in and half its chirp, s.
    total_s : float
        The session's total stimulation, s.

    Examples
    --------
    >>> from types import SimpleNamespace as T
    >>> tr = [T(n_samples=30, fs_Hz=2.0, steady_s=5.0, chirp_s=10.0)] * 3
    >>> cumulative_stimulation_s(tr)
    (array([10., 25., 40.]), 45.0)
    """
    before = 0.0
    centre = []
    for tr in trials:
        dur = float(tr.n_samples) / float(tr.fs_Hz)
        centre.append(before + min(float(tr.steady_s) + 0.5 * float(tr.chirp_s), dur))
        before += dur
    return np.asarray(centre, dtype=float), before


def gains_between_repeats(trials, steady_s: float | None = None) -> np.ndarray:
    """Each trial's gain relative to the mean of its level's repeats, without a model.

    Per level, the chirp part of every trial (from ``steady_s``, linear trend removed) is
    projected on the level's mean: ``g_i = <y_i, ybar> / <ybar, ybar>`` (1 = an average
    repeat). Sensor noise averages out of the dot products; a level with one trial gets
    NaN.

    Parameters
    ----------
    trials : sequence of Trial
        Completed trials with finite force (any order, several levels).
    steady_s : float, optional
        Start of the chirp window (default: each trial's ``steady_s``).

    Returns
    -------
    (n_trials,) ndarray
    """
    out = np.full(len(trials), np.nan)
    groups: dict[float, list[int]] = {}
    for i, t in enumerate(trials):
        groups.setdefault(round(float(t.sE), 9), []).append(i)
    for idx in groups.values():
        if len(idx) < 2:
            continue
        rows = []
        for i in idx:
            t = trials[i]
            k0 = round((t.steady_s if steady_s is None else steady_s) * t.fs_Hz)
            rows.append(np.asarray(t.force_N, float)[k0:])
        n = min(len(r) for r in rows)
        if n < 16:
            continue
        x = np.arange(n, dtype=float)
        Y = np.vstack([r[:n] for r in rows])
        A = np.column_stack([np.ones(n), x])
        Y = Y - (Y @ np.linalg.pinv(A).T) @ A.T
        ybar = Y.mean(axis=0)
        den = float(ybar @ ybar)
        if den > 0:
            out[idx] = (Y @ ybar) / den
    return out
