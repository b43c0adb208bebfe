"""Trial-to-trial scatter: how much Kp, wn and zeta vary between repeats of one sE.

The paper fits one second-order model to the *average* of a level's repeats. Muscles do
not answer two identical stimulations identically (motor-unit recruitment, electrode-skin
contact, posture, fatigue and potentiation move from trial to trial), so a held-out repeat
differs from any model of the average by this scatter even when the model is exactly
right. Here each usable repeat is fitted on its own (same preprocessing, same input timing
and the level's fit as the start) and the scatter is summarised per sE and per parameter.

Statistic. For a parameter ``p`` the scatter is the standard deviation of ``ln p`` between
the repeats of a level, in percent: for the few-percent scatter of a repeatable
preparation it is the coefficient of variation (CV). With ``n`` repeats it has ``n - 1``
degrees of freedom; its 95 % confidence interval is the chi-square interval
``s sqrt(dof / chi2_{0.975, dof})`` to ``s sqrt(dof / chi2_{0.025, dof})`` (normal
log-parameters). Pooled over the levels, ``s^2 = sum (n_j - 1) s_j^2 / sum (n_j - 1)``
with ``sum (n_j - 1)`` degrees of freedom: with 15 levels x 3 repeats, 30 degrees of
freedom bound a CV of 10 % within about 8-13 %.

Part of the observed scatter is estimation noise (sensor noise through each repeat's own
fit): its share is the mean squared relative standard error of the per-trial fits. The
*physiological* CV is ``sqrt(max(s^2 - est^2, 0))``; both are reported.

When the session shows significant fatigue (:mod:`nmsid.analysis.fatigue`) the Kp
scatter is computed on gains corrected for it (the trend is not scatter), and the result
says so.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.fatigue import FatigueResult, chi2_ppf
from nmsid.analysis.preprocess import TrialSignals, preprocess_trials
from nmsid.analysis.second_order import fit_second_order
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.reprs import counted, html_repr, short_repr, to_dataframe

#: The three parameters, as named in ``parameters.csv``.
PARAMETERS = ("Kp", "wn_rad_s", "zeta")


@dataclass(frozen=True)
class TrialFit:
    """The second-order model of one repeat fitted on its own."""

    name: str
    sE: float
    repeat: int
    Kp: float
    wn_rad_s: float
    zeta: float
    Kp_se: float
    wn_se: float
    zeta_se: float
    fit_pct: float
    cum_stim_s: float
    """Cumulative stimulation at the centre of the trial's analysis window, s."""


@dataclass(frozen=True)
class ParameterScatter:
    """The scatter of one parameter between repeats (one level, or pooled).

    Attributes
    ----------
    parameter : str
        ``Kp``, ``wn_rad_s`` or ``zeta``.
    cv_pct : float
        Standard deviation of the log-parameter between repeats, percent (about the CV).
    ci_low_pct, ci_high_pct : float
        Its 95 % chi-square confidence interval.
    estimation_cv_pct : float
        The part expected from the per-trial fits' own standard errors (RMS relative SE).
    physiological_cv_pct : float
        ``sqrt(max(cv^2 - estimation^2, 0))``: the scatter of the participant.
    n_trials : int
    dof : int
    """

    parameter: str
    cv_pct: float
    ci_low_pct: float
    ci_high_pct: float
    estimation_cv_pct: float
    physiological_cv_pct: float
    n_trials: int
    dof: int


@dataclass(frozen=True)
class LevelScatter:
    """The scatter of the three parameters at one sE."""

    sE: float
    n_trials: int
    Kp: ParameterScatter
    wn_rad_s: ParameterScatter
    zeta: ParameterScatter


@dataclass(frozen=True)
class ScatterResult:
    """Trial-to-trial scatter of a session: per-trial fits, per sE and pooled.

    Attributes
    ----------
    trials : tuple of TrialFit
    levels : tuple of LevelScatter
        Levels with two or more fitted repeats.
    Kp, wn_rad_s, zeta : ParameterScatter
        Pooled over the levels.
    fatigue_corrected : bool
        Kp's scatter is computed on gains corrected for significant fatigue.
    problems : tuple of str
        Repeats that could not be fitted on their own, and why.
    """

    trials: tuple[TrialFit, ...]
    levels: tuple[LevelScatter, ...]
    Kp: ParameterScatter
    wn_rad_s: ParameterScatter
    zeta: ParameterScatter
    fatigue_corrected: bool = False
    problems: tuple[str, ...] = ()

    def rows(self) -> list[dict]:
        """One dict per trial fitted on its own (:class:`TrialFit`)."""
        return [asdict(t) for t in self.trials]

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        return short_repr("ScatterResult", counted(len(self.trials), "trial fit"),
                          ", ".join(f"{p.parameter} CV {p.cv_pct:.3g} %"
                                    for p in (self.Kp, self.wn_rad_s, self.zeta)),
                          "fatigue-corrected Kp" if self.fatigue_corrected else "",
                          counted(len(self.problems), "problem") if self.problems else "")

    _repr_html_ = html_repr

    def pooled(self, parameter: str) -> ParameterScatter:
        """The pooled scatter of ``Kp``, ``wn_rad_s`` or ``zeta``."""
        if parameter not in PARAMETERS:
            raise ValueError(f"parameter {parameter!r}: use one of {PARAMETERS}")
        return getattr(self, parameter)

    def sentence(self) -> str:
        """Pooled scatter in one line."""
        if self.Kp.dof == 0:
            return "trial-to-trial scatter not estimated (no sE with two fitted repeats)"
        parts = [f"{p} {s.cv_pct:.1f} % ({s.ci_low_pct:.1f}-{s.ci_high_pct:.1f} %)"
                 for p, s in ((n, self.pooled(n)) for n in PARAMETERS)]
        return ("trial-to-trial scatter between repeats (CV, 95 % CI, "
                f"{self.Kp.dof} degrees of freedom): " + ", ".join(parts)
                + (" [Kp corrected for fatigue]" if self.fatigue_corrected else ""))

    def table(self) -> str:
        """Per-sE scatter as aligned text."""
        lines = [f"{'sE':>5} {'n':>2} {'CV Kp %':>8} {'CV wn %':>8} {'CV zeta %':>9}"]
        for lv in self.levels:
            lines.append(f"{lv.sE:5.2f} {lv.n_trials:2d} {lv.Kp.cv_pct:8.2f} "
                         f"{lv.wn_rad_s.cv_pct:8.2f} {lv.zeta.cv_pct:9.2f}")
        lines.append(self.sentence())
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return asdict(self)


def _chi2_ci(s: float, dof: int) -> tuple[float, float]:
    if dof < 1 or not math.isfinite(s):
        return float("nan"), float("nan")
    return (s * math.sqrt(dof / chi2_ppf(0.975, dof)),
            s * math.sqrt(dof / chi2_ppf(0.025, dof)))


def _summary(name: str, groups: list[np.ndarray], rel_se: list[np.ndarray]
             ) -> ParameterScatter:
    """Pooled log-SD of ``groups`` (one array of positive values per level)."""
    ss, dof, n = 0.0, 0, 0
    for g in groups:
        g = g[np.isfinite(g) & (g > 0)]
        if len(g) >= 2:
            lg = np.log(g)
            ss += float(np.sum((lg - lg.mean()) ** 2))
            dof += len(g) - 1
            n += len(g)
    nan = float("nan")
    if dof == 0:
        return ParameterScatter(name, nan, nan, nan, nan, nan, n, 0)
    s = math.sqrt(ss / dof)
    lo, hi = _chi2_ci(s, dof)
    r = np.concatenate(rel_se) if rel_se else np.empty(0)
    r = r[np.isfinite(r)]
    est = float(np.sqrt(np.mean(r ** 2))) if len(r) else nan
    phys = math.sqrt(max(s * s - est * est, 0.0)) if math.isfinite(est) else s
    return ParameterScatter(name, 100 * s, 100 * lo, 100 * hi, 100 * est, 100 * phys, n, dof)


def summarise(trials: list[TrialFit] | tuple[TrialFit, ...],
              fatigue: FatigueResult | None = None, problems=()) -> ScatterResult:
    """The per-sE and pooled scatter of per-trial fits (see module).

    Parameters
    ----------
    trials : sequence of TrialFit
    fatigue : FatigueResult, optional
        When significant, each Kp is divided by the fitted gain factor at its
        cumulative stimulation before the scatter is computed.
    problems : sequence of str
        Carried into the result.

    Returns
    -------
    ScatterResult
    """
    trials = tuple(trials)
    corrected = bool(fatigue is not None and fatigue.significant and fatigue.estimated)
    lam = fatigue.rate_per_100s / 100.0 if corrected and fatigue is not None else 0.0
    by_level: dict[float, list[TrialFit]] = {}
    for t in trials:
        by_level.setdefault(round(t.sE, 9), []).append(t)

    def values(ts, p):
        v = np.array([getattr(t, p) for t in ts], dtype=float)
        if p == "Kp" and lam:
            v = v * np.exp(lam * np.array([t.cum_stim_s for t in ts]))
        return v

    def rel(ts, p):
        return np.array([getattr(t, p.replace("_rad_s", "") + "_se") / getattr(t, p)
                         for t in ts], dtype=float)

    levels = []
    for key in sorted(by_level):
        ts = by_level[key]
        if len(ts) < 2:
            continue
        per = {p: _summary(p, [values(ts, p)], [rel(ts, p)]) for p in PARAMETERS}
        levels.append(LevelScatter(sE=float(key), n_trials=len(ts), **per))
    groups = [by_level[k] for k in sorted(by_level)]
    pooled = {p: _summary(p, [values(ts, p) for ts in groups], [rel(ts, p) for ts in groups])
              for p in PARAMETERS}
    return ScatterResult(trials=trials, levels=tuple(levels), fatigue_corrected=corrected,
                         problems=tuple(problems), **pooled)


def fit_trials(level_trials, level_fits, cum_stim_s: dict[int, float],
               settings: IdentificationSettings | None = None, *,
               cache: TrialSignals | None = None) -> tuple[list[TrialFit], list[str]]:
    """Fit every usable repeat on its own.

    Parameters
    ----------
    level_trials : sequence of sequence of Trial
        Per level, the repeats the level's fit used.
    level_fits : sequence of (LevelData, SecondOrderFit)
        Per level, its preprocessed data (for the input delay) and fit (the start).
    cum_stim_s : dict
        ``id(trial)`` -> cumulative stimulation at its window centre, s.
    settings : IdentificationSettings, optional
    cache : TrialSignals, optional
        The repeats as filtered for their level's fit (not filtered again).

    Returns
    -------
    fits : list of TrialFit
    problems : list of str
        One line per repeat that could not be fitted alone.
    """
    s = settings or IdentificationSettings()
    out: list[TrialFit] = []
    problems: list[str] = []
    for trials, (data, fit) in zip(level_trials, level_fits, strict=True):
        if len(trials) < 2:
            continue
        for tr in trials:
            try:
                d = preprocess_trials([tr], s, input_delay_s=data.input_delay_s, cache=cache)
                f = fit_second_order(d.u, d.y_N, d.fs_Hz, s, band_Hz=d.band_Hz,
                                     start=(fit.wn_rad_s, fit.zeta), t0_s=float(d.t_s[0]))
            except (IdentificationError, np.linalg.LinAlgError, ArithmeticError) as exc:
                problems.append(f"trial {tr.name} (sE={tr.sE:g}): not fitted on its own "
                                f"({exc}); left out of the scatter")
                continue
            if not (f.converged and f.Kp > 0 and f.wn_rad_s > 0 and f.zeta > 0):
                problems.append(f"trial {tr.name} (sE={tr.sE:g}): its own fit did not "
                                "converge to a positive model; left out of the scatter")
                continue
            out.append(TrialFit(name=tr.name, sE=float(tr.sE), repeat=int(tr.repeat),
                                Kp=f.Kp, wn_rad_s=f.wn_rad_s, zeta=f.zeta, Kp_se=f.Kp_se,
                                wn_se=f.wn_se, zeta_se=f.zeta_se, fit_pct=f.fit_pct,
                                cum_stim_s=float(cum_stim_s.get(id(tr), float("nan")))))
    return out, problems
