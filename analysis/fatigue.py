"""Within-session fatigue: the gain lost with accumulated stimulation, with its uncertainty.

FES recruits the same motor units at every pulse, so the force a given stimulation
produces falls through a session (fatigue) or, early on, rises (potentiation). The
session's own structure measures it: the schedule is randomised, so the repeats of one sE
fall at different times, and each trial's gain compared with the other repeats of *its
own* sE tells how the gain moved with the stimulation given before it. Nothing about the
participant's curves over sE is assumed.

Rate and significance (one shared rate, one free gain per sE level)::

    ln g_ij = a_j - lambda c_ij + e_ij

``g_ij`` is the gain of trial ``i`` at level ``j`` (the identified per-trial Kp, or a
trial's gain relative to a model), ``c_ij`` the cumulative stimulation time (s) at the
centre of its analysis window, ``a_j`` the level's unfatigued log-gain and ``e_ij`` the
trial-to-trial scatter. It is a linear fixed-effects regression: ``lambda`` is the slope of
the within-level deviations of ``ln g`` on those of ``c``, in closed form, and its standard
error is ``s / sqrt(Sxx)`` with ``s^2`` the residual variance on ``n - L - 1`` degrees of
freedom (``L`` levels with at least two trials). ``z = lambda / se`` decides significance.

Loss and its interval: the shape of the decline. Fatigue is not always a constant
relative rate: the first-order fatigue models (Riener et al. 1996, Ding et al. 2000) lose
force fast and then level off (saturating), a protocol may lose it linearly, and a
constant-rate fit of a saturating loss extrapolates the unfatigued gain too low and
reports too little loss with a too narrow interval. The gain is therefore also fitted as

    ln g_ij = a_j + ln(1 - D s_r(c_ij)),   s_r(c) = (1 - exp(-r c / C)) / (1 - exp(-r))

with ``D`` the fraction lost over the session's total stimulation ``C`` and ``r`` the
shape (``r = 0``: linear, ``s = c / C``; ``r > 0``: saturating with time constant
``C / r``; ``r < 0``: accelerating; a constant relative rate is ``r = -ln(1 - D)``),
on a grid of ``(r, D)`` with the level gains ``a_j`` in closed form. The reported shape is
the one of least AICc among ``exponential`` (the rate above), ``linear`` (``r = 0``) and
``saturating`` (``r`` free, one parameter more); the loss is that model's ``D``. Its 95 %
interval is the profile-likelihood interval of ``D`` with the shape free (``r`` minimised
at every ``D``): ``RSS(D) <= RSS_min (1 + t^2 / dof)``, ``dof = n - L - 2``, so it holds
whether the loss is linear, exponential or saturating, and widens when the data cannot
tell the shapes apart.

The effect is *significant* when ``|lambda|`` exceeds ``z_crit`` standard errors, or the
shape-free fit beats the levels alone by a likelihood ratio ``n ln(RSS_0 / RSS_min)``
beyond the 2-dof chi-square quantile at ``z_crit``'s level plus ``SHAPE_LR_MARGIN`` (a
fast-then-flat loss the constant-rate slope misses), and the loss (or gain) over the
session is at least ``min_effect_pct`` percent.
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
    shape: str = "exponential"
    """The decline's form of least AICc: ``exponential`` (constant relative rate),
    ``linear`` or ``saturating`` (see module)."""
    shape_r: float = float("nan")
    """Its shape parameter ``r`` (0: linear; ``C / r`` the saturating time constant)."""

    def gain_at(self, cumulative_stim_s):
        """The fitted gain relative to the unfatigued one after ``cumulative_stim_s`` of
        stimulation (the reported shape; NaN when nothing was estimated)."""
        c = np.asarray(cumulative_stim_s, dtype=float)
        d = self.loss_pct / 100.0
        return 1.0 - d * _shape(self.shape_r, c / self.total_stim_s)

    @property
    def estimated(self) -> bool:
        """True when a rate was estimated (enough repeats spread in time)."""
        return math.isfinite(self.loss_pct)

    def sentence(self) -> str:
        """The result in one line a physiologist reads."""
        if not self.estimated:
            return f"fatigue not estimated: {self.note}"
        lost = self.loss_pct >= 0
        word = ("fatigue" if lost else "potentiation") if self.significant \
            else "no significant fatigue"
        # one sign convention for the figure and its interval: a loss with the interval
        # of the loss, a gain with the interval of the gain (its negative)
        lo, hi = (self.ci_low_pct, self.ci_high_pct) if lost else \
            (-self.ci_high_pct, -self.ci_low_pct)
        shape = f", {self.shape} decline" if self.shape and self.significant else ""
        return (f"{word}: the gain {'lost' if lost else 'gained'} {abs(self.loss_pct):.1f} % "
                f"(95 % CI {lo:.1f} to {hi:.1f} % {'lost' if lost else 'gained'}) over "
                f"{self.total_stim_s:.0f} s of stimulation{shape} (z = {self.z:.1f}; "
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
                         note, shape="")


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
    est, lo, hi = loss(lam), loss(lam - t * se), loss(lam + t * se)
    se_pct = 100.0 * total * math.exp(-lam * total) * se
    shape, r = "exponential", float("nan")
    shape_sig = False
    if dof >= 2 and s2 > 0:
        sh = shape_fit(y, lev, c / total, float(resid @ resid), est / 100.0)
        if sh is not None:
            shape, r, est, lo, hi, lr = sh
            # a loss the constant-rate slope misses (fast, then flat) is significant on
            # the shape-free likelihood ratio at the same level as z_crit (2 dof)
            shape_sig = lr >= -2.0 * math.log(2.0 * _normal_sf(z_crit)) + SHAPE_LR_MARGIN
    significant = bool((abs(z) >= z_crit or shape_sig) and abs(est) >= min_effect_pct)
    return FatigueResult(loss_pct=est, ci_low_pct=lo, ci_high_pct=hi, se_pct=se_pct,
                         rate_per_100s=100.0 * lam, z=float(z), significant=significant,
                         total_stim_s=total, n_trials=n, n_levels=n_levels, dof=dof,
                         residual_sd_pct=100.0 * math.sqrt(s2), source=source,
                         shape=shape, shape_r=r)


#: Added to the shape-free likelihood ratio's threshold: the shape ``r`` is not defined
#: without fatigue, and the maximum over it makes the 2-dof chi-square anti-conservative
#: (without a margin, 9 false reports in 600 simulated fatigue-free sessions of 2-10 %
#: scatter at z_crit = 3; with 8, 4, against 3 of the slope test alone).
SHAPE_LR_MARGIN = 8.0

#: Shapes tried (``r``, see module): accelerating (< 0), linear (0), saturating (> 0) down
#: to a time constant of 1/20 of the session's stimulation.
SHAPE_R = np.concatenate([np.linspace(-4.0, -0.25, 8), [0.0], np.geomspace(0.1, 20.0, 28)])

#: Fractions of the gain lost over the session tried (negative: potentiation).
LOSS_GRID = np.linspace(-0.8, 0.95, 351)


def _shape(r, x):
    """``s_r(x)`` of the module, ``x = c / C``: 0 at the start, 1 at the session's end."""
    r = np.asarray(r, dtype=float)
    x = np.asarray(x, dtype=float)
    small = np.abs(r) < 1e-9
    rs = np.where(small, 1.0, r)
    out = -np.expm1(-rs * x) / -np.expm1(-rs)
    return np.where(small, x, out)


def _normal_sf(z: float) -> float:
    """P(Z > z) of the standard normal."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def _aicc(rss: float, n: int, k: int) -> float:
    return n * math.log(rss / n) + 2 * k + 2 * k * (k + 1) / max(n - k - 1, 1)


def shape_fit(y: np.ndarray, lev: np.ndarray, x: np.ndarray, rss_exponential: float,
              loss_exponential: float):
    """The loss over the session with a free shape (see module).

    Parameters
    ----------
    y : ndarray
        ``ln g`` of the trials of levels with two or more trials... and the others
        (a level with one trial fits its own ``a_j`` exactly and is ignored).
    lev : ndarray
        Level labels.
    x : ndarray
        Cumulative stimulation over the session's total.
    rss_exponential, loss_exponential : float
        The constant-rate fit's residual sum of squares and its loss (fraction).

    Returns
    -------
    tuple or None
        ``(shape, r, loss_pct, ci_low_pct, ci_high_pct)``; None when the data are too few.
    """
    keys = [k for k in dict.fromkeys(lev.tolist()) if (lev == k).sum() >= 2]
    m = np.isin(lev, keys)
    y, lev, x = y[m], lev[m], x[m]
    n, n_lev = len(y), len(keys)
    dof = n - n_lev - 2
    if dof < 1:
        return None
    S = _shape(SHAPE_R[:, None], x[None, :])                          # (R, n)
    D = LOSS_GRID
    with np.errstate(invalid="ignore", divide="ignore"):
        F = np.log(1.0 - D[None, :, None] * S[:, None, :])              # (R, D, n)
    # each level's own gain a_j in closed form: the residual's within-level deviations,
    # (I - P) with P the projection on the level indicators
    ind = (lev[:, None] == np.array(keys, dtype=lev.dtype)[None, :]).astype(float)
    W = np.eye(n) - ind @ (ind / ind.sum(axis=0)).T
    E = (y[None, None, :] - F).reshape(-1, n) @ W
    rss = np.sum(E ** 2, axis=-1).reshape(F.shape[:2])
    rss = np.where(np.isfinite(rss), rss, np.inf)                       # (R, D)
    best = float(rss.min())
    if not (math.isfinite(best) and best > 0):
        return None
    lin = int(np.flatnonzero(SHAPE_R == 0.0)[0])
    k_lin = int(np.argmin(rss[lin]))
    i_sat, k_sat = np.unravel_index(int(np.argmin(rss)), rss.shape)
    fits = {"exponential": (_aicc(rss_exponential, n, n_lev + 1), float("nan"),
                            loss_exponential),
            "linear": (_aicc(float(rss[lin, k_lin]), n, n_lev + 1), 0.0,
                       _vertex(D, rss[lin], k_lin)),
            "saturating": (_aicc(best, n, n_lev + 2), float(SHAPE_R[i_sat]),
                           _vertex(D, rss[i_sat], int(k_sat)))}
    shape = min(fits, key=lambda k: fits[k][0])
    _, r, est = fits[shape]
    if shape == "exponential":
        r = -math.log1p(-est) if est < 1 else float("nan")
    prof = rss.min(axis=0)
    inside = prof <= best * (1.0 + t_ppf(0.975, dof) ** 2 / dof)
    thr = best * (1.0 + t_ppf(0.975, dof) ** 2 / dof)
    ks = np.flatnonzero(inside)
    lo = _crossing(D, prof, thr, ks[0], ks[0] - 1)
    hi = _crossing(D, prof, thr, ks[-1], ks[-1] + 1)
    # a bound on the grid's edge is no bound: say so (all of it lost, or -inf)
    lo_pct = -math.inf if ks[0] == 0 else 100.0 * lo
    hi_pct = 100.0 if ks[-1] == len(D) - 1 else 100.0 * hi
    est_pct = 100.0 * est
    rss0 = float(rss[0, int(np.argmin(np.abs(D)))]) if np.any(D == 0.0) else math.inf
    lr = n * math.log(rss0 / best) if math.isfinite(rss0) else 0.0
    return (shape, float(r), est_pct, min(lo_pct, est_pct), max(hi_pct, est_pct), lr)


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


def _crossing(D: np.ndarray, prof: np.ndarray, thr: float, k_in: int, k_out: int) -> float:
    """Where the profile crosses the threshold between a grid point inside the interval
    and its neighbour outside (linear interpolation; the inside point at the grid's
    edge)."""
    if k_out < 0 or k_out >= len(D) or not math.isfinite(float(prof[k_out])):
        return float(D[k_in])
    a, b = float(prof[k_in]), float(prof[k_out])
    w = (thr - a) / (b - a) if b > a else 0.0
    return float(D[k_in] + w * (D[k_out] - D[k_in]))


def _vertex(D: np.ndarray, row: np.ndarray, k: int) -> float:
    """The minimum of ``row`` over ``D`` refined by a parabola through the grid's least
    point and its neighbours (the grid point itself at an edge)."""
    if k <= 0 or k >= len(D) - 1 or not np.all(np.isfinite(row[k - 1:k + 2])):
        return float(D[k])
    a, b, c = (float(v) for v in row[k - 1:k + 2])
    den = a - 2 * b + c
    if not den > 0:
        return float(D[k])
    return float(D[k] + 0.5 * (a - c) / den * (D[1] - D[0]))
