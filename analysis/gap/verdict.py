"""The verdict: is there a gap beyond noise, does a candidate explain it, what remains, where.

Noise reference. Each trial's steady lead-in (rE = 0.5, no model involved) gives the power
of its measurement noise as the force is filtered (``GapData.steady_noise_N2``). A model's
held-out residual power in the window of trial ``i``, ``P_i``, is compared with that trial's
noise power ``N_i``: ``ratio_i = P_i / N_i`` is about 1 when the model predicts the repeat as
well as the noise allows.

Significance. The statistic is the *median* over the held-out trials of ``ln ratio_i``, so
the verdict never rests on one or two trials (a voluntary contraction or a spike in one
trial moves a mean, not the median). Its standard error is ``1.2533 s / sqrt(n)`` with ``s``
the larger of the spread expected from the effective sample counts of window and lead-in
(``2 / N_eff`` per power estimate) and the observed robust spread (1.4826 MAD) of the
trials' log-ratios. A gap is *significant* when the median exceeds ``significance_z``
standard errors and the gap beyond noise is at least ``min_beyond_noise_pct`` (NRMSE
points of the response: below that no physiologist would call the twin wrong).

Trial-to-trial variability. Muscles do not answer two identical stimulations identically:
Kp, wn and zeta move between repeats (:mod:`nmsid.analysis.scatter`), so a held-out repeat
differs from any model of the others by that scatter even when the model is exactly right,
and the test above alone would call it a gap. The misfit is therefore split into the part
*common to the repeats* of an sE (what a better model could capture) and the part that
differs between them. Per level, the mean of the repeats' held-out residuals carries the
common part plus the sensor noise averaged over ``n`` repeats (lead-in noise power / ``n``);
trial-to-trial deviations that a second-order model can follow cancel in it (each repeat is
predicted from the others, whose deviations average out). The same median-log-ratio test
is applied to these level means against ``N / n`` (:func:`common_test`): a broadband gap is
significant only when the per-trial test *and* this common-part test are (for the nominal
model when no candidate is supported: a supported candidate - fatigue, a drift - may
explain what differs between repeats, and is named on the per-trial test). A misfit beyond
sensor noise whose common part is not significant is reported as trial-to-trial
variability, with both figures: the common part (``systematic_pct``) and the part that
differs between repeats (``trial_to_trial_pct``), beside the scatter between repeats measured
without a model (``Diagnosis.noise_floor_nrmse_pct``).

Fatigue. The gain of each trial relative to the nominal model fitted on all trials, against the
cumulative stimulation before it, gives the session's fatigue
(:func:`nmsid.analysis.fatigue.fit_fatigue`, levels as fixed effects): reported with its
magnitude and confidence interval, and named in the sentence when significant.

Narrow-band components. The mean periodogram of the held-out residual is searched for
peaks above a running-median background. A peak as narrow as the frequency resolution, at
the same frequency in every trial, is an instrument line (mains, the stimulator's carrier or
their aliases): listed, not counted. A wider peak (a physiological oscillation, e.g.
tremor at 8-12 Hz) whose power beyond the background is material is an unexplained
component and makes the remaining gap significant.

Verdict. ``none``: the nominal gap is not significant (a candidate that would fit a gap
within noise is reported as such, not named). ``effect`` / ``pair``: a candidate (pair) is
supported and the nominal gap is significant; ``remaining`` then says whether what it
leaves is still significant. ``unexplained``: the nominal gap is significant and no
candidate or pair is supported. ``likely``: the same, but one candidate wins on evidence
(``dIC < -ic_margin``) and shrinks the held-out NRMSE by less than ``min_shrink_pct`` while
trial-to-trial scatter dominates the held-out error (:func:`likely_candidate`): the
held-out test cannot separate it from scatter, so the verdict names it as *likely*, with
its evidence and the repeats of each sE that would decide - never "something else". ``muscle_twin``:
the template's answer still leaves a significant gap and the physiological twin
(:mod:`nmsid.analysis.muscle`) predicts the held-out repeats better (see
:mod:`nmsid.analysis.muscle.candidate`); ``remaining`` is then its own. Narrow-band components:
:mod:`nmsid.analysis.gap.narrowband`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from itertools import pairwise
from typing import Any

import numpy as np

from nmsid.analysis.fatigue import FatigueResult, fit_fatigue
from nmsid.analysis.gap.fit import find_steps, predict
from nmsid.analysis.gap.harmonics import local_harmonics
from nmsid.analysis.gap.models import nuisance_basis
from nmsid.analysis.gap.narrowband import narrow_band
from nmsid.analysis.gap.samples import effective_fraction
from nmsid.protocols.effects import CANDIDATES, WORDS

#: Residual harmonics examined (1.5f: a non-harmonic reference).
HARMONIC_ORDERS = (1, 1.5, 2, 3)

#: Plain words for each effect (the report's sentence), declared with each effect.
EFFECT_WORDS = WORDS


def effect_words(label: str) -> str:
    """Plain words for an effect or a pair label ``a+b``."""
    return " together with ".join(EFFECT_WORDS.get(p, p) for p in label.split("+"))


def _count_words(n: int) -> str:
    """``n`` in words up to twelve, else digits (the report's sentence)."""
    names = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine",
             "ten", "eleven", "twelve")
    return names[n] if 0 <= n < len(names) else str(n)


def _mad_sd(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if len(x) else float("nan")


@dataclass(frozen=True)
class GapTest:
    """A held-out residual against the noise (:func:`gap_test`, :func:`common_test`).

    Attributes
    ----------
    n_trials : int
        Trials (or levels) with a measurable lead-in noise.
    significant : bool
        The median log-ratio exceeds ``z_crit`` standard errors and the typical gap beyond
        noise is at least ``min_beyond_noise_pct``.
    beyond_noise_pct, beyond_noise_pct_typical : float or None
        Misfit beyond noise (% of the response): from all trials, and from the median
        ratio. None when not tested.
    median_ratio : float or None
        Median over trials of residual power / noise power.
    z : float or None
        The median log-ratio in standard errors.
    concentrated_in : tuple
        Trials that carry more than half of the excess, when at most two do.
    concentrated_share_pct : float or None
        Their share of the excess (%), when ``concentrated_in`` is not empty.
    note : str or None
        Why the test was not made.
    """

    n_trials: int
    significant: bool = False
    beyond_noise_pct: float | None = None
    beyond_noise_pct_typical: float | None = None
    median_ratio: float | None = None
    z: float | None = None
    concentrated_in: tuple = ()
    concentrated_share_pct: float | None = None
    note: str | None = None

    def to_dict(self) -> dict:
        """The former dict form (``concentrated_share_pct`` and ``note`` only when set)."""
        out: dict[str, Any] = {
            "n_trials": self.n_trials, "significant": self.significant,
            "beyond_noise_pct": self.beyond_noise_pct,
            "beyond_noise_pct_typical": self.beyond_noise_pct_typical,
            "median_ratio": self.median_ratio, "z": self.z,
            "concentrated_in": list(self.concentrated_in)}
        if self.concentrated_share_pct is not None:
            out["concentrated_share_pct"] = self.concentrated_share_pct
        if self.note is not None:
            out["note"] = self.note
        return out


@dataclass(frozen=True)
class MisfitSplit:
    """The misfit beyond noise split into its common and trial-to-trial parts
    (:func:`split_misfit`).

    Attributes
    ----------
    systematic_pct : float or None
        Part common to the repeats of each sE (% of the response, beyond noise); None
        when the common part could not be tested.
    trial_to_trial_pct : float or None
        Part that differs between repeats (%).
    within_scatter : bool
        The per-trial test is significant, the common part is not.
    systematic_significant : bool or None
        The common part is significant and material.
    """

    systematic_pct: float | None
    trial_to_trial_pct: float | None
    within_scatter: bool
    systematic_significant: bool | None

    def to_dict(self) -> dict:
        """Plain form (the report's ``remaining`` / ``nominal_gap`` keys)."""
        return {"systematic_pct": self.systematic_pct,
                "trial_to_trial_pct": self.trial_to_trial_pct,
                "within_scatter": self.within_scatter,
                "systematic_significant": self.systematic_significant}


@dataclass(frozen=True)
class ResidualWhere:
    """Where a held-out residual exceeds the noise (:func:`where`).

    Attributes
    ----------
    sE : tuple of dict
        Per level: ``sE``, ``ratio_to_noise`` (median over its trials), ``n_trials``.
    chirp_band : tuple of dict
        Per chirp band: ``f_lo_Hz``, ``f_hi_Hz``, ``ratio_to_noise``.
    trial_position : dict
        ``ratio_to_noise_by_third`` of the session and ``correlation_with_order``.
    narrow_band : list of dict
        The narrow-band components (:mod:`nmsid.analysis.gap.narrowband`).
    harmonics : dict or None
        Median residual at each harmonic order and those in excess.
    summary : str
        The one-line summary ('' when nothing stands out or too few trials).
    """

    sE: tuple = ()
    chirp_band: tuple = ()
    trial_position: dict = field(default_factory=dict)
    narrow_band: list = field(default_factory=list)
    harmonics: dict | None = None
    summary: str = ""

    def to_dict(self) -> dict:
        """The report's ``where`` part, as written."""
        return {"sE": list(self.sE), "chirp_band": list(self.chirp_band),
                "trial_position": self.trial_position, "narrow_band": self.narrow_band,
                "harmonics": self.harmonics, "summary": self.summary}


def gap_test(resid: np.ndarray, noise_N2: np.ndarray, reference: np.ndarray,
             nu_window: float, nu_lead: float, n_lead: int, *, z_crit: float = 3.0,
             min_beyond_noise_pct: float = 0.1, names=None) -> GapTest:
    """Is a residual significantly beyond the noise? (see module)

    Parameters
    ----------
    resid : (n_trials, n_eval) ndarray
        Held-out residual of the model, one row per tested trial.
    noise_N2 : (n_trials,) ndarray
        Each trial's noise power from its steady lead-in.
    reference : (n_trials, n_eval) ndarray
        The measured force (offset and trend removed): the NRMSE's denominator.
    nu_window, nu_lead : float
        Effective-sample fractions of the noise at the evaluation rate.
    n_lead : int
        Samples of a lead-in segment.
    names : list of str, optional
        Trial names (for the concentration note).

    Returns
    -------
    GapTest
        ``beyond_noise_pct`` (all trials), ``beyond_noise_pct_typical`` (from the median
        ratio), ``median_ratio``, ``z``, ``significant``, ``concentrated_in`` (trials that
        carry more than half of the excess, when at most two do) and ``n_trials``.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> noise = rng.normal(0, 0.1, (30, 1000))
    >>> ref = np.sin(np.linspace(0, 60, 1000))[None, :].repeat(30, 0)
    >>> gap_test(noise, np.full(30, 0.01), ref, 0.5, 0.5, 300).significant
    False
    >>> gap_test(noise + 0.05, np.full(30, 0.01), ref, 0.5, 0.5, 300).significant
    True
    """
    ok = np.isfinite(noise_N2) & (noise_N2 > 0)
    if ok.sum() < 3:
        return GapTest(n_trials=int(ok.sum()), note="fewer than three trials with a "
                       "measurable lead-in noise: not tested")
    r, N, ref = resid[ok], noise_N2[ok], reference[ok]
    P = np.mean(r ** 2, axis=1)
    ref_ms = float(np.mean(ref ** 2))
    lr = np.log(P / N)
    n = len(lr)
    n_win = max(1.0, nu_window * r.shape[1])
    n_ld = max(1.0, nu_lead * n_lead)
    s_expected = math.sqrt(2.0 / n_win + 2.0 / n_ld)
    s = max(s_expected, _mad_sd(lr))
    med = float(np.median(lr))
    z = med / (1.2533 * s / math.sqrt(n))
    beyond_all = 100.0 * math.sqrt(max(float(np.mean(P - N)), 0.0) / ref_ms)
    beyond_typ = 100.0 * math.sqrt(max(math.expm1(med), 0.0) * float(np.median(N)) / ref_ms)
    excess = np.maximum(P - N, 0.0)
    total = float(excess.sum())
    conc: list = []
    share = None
    if total > 0 and beyond_all >= max(min_beyond_noise_pct, 2.0 * beyond_typ):
        order = np.argsort(excess)[::-1]
        for k in (1, 2):
            if float(excess[order[:k]].sum()) > 0.5 * total:
                idx = np.flatnonzero(ok)[order[:k]]
                conc = [str(names[i]) if names is not None else int(i) for i in idx]
                share = 100.0 * float(excess[order[:k]].sum()) / total
                break
    return GapTest(n_trials=int(ok.sum()), beyond_noise_pct=beyond_all,
                   beyond_noise_pct_typical=beyond_typ, median_ratio=math.exp(med), z=z,
                   concentrated_in=tuple(conc), concentrated_share_pct=share,
                   significant=bool(z > z_crit and beyond_typ >= min_beyond_noise_pct))


def common_test(resid: np.ndarray, noise_N2: np.ndarray, reference: np.ndarray,
                level: np.ndarray, sE_levels, nu: float, n_lead: int, *, z_crit: float = 3.0,
                min_beyond_noise_pct: float = 0.1) -> GapTest | None:
    """Is the part of a residual common to the repeats of each sE beyond noise? (see module)

    Parameters
    ----------
    resid, reference : (n_trials, n_eval) ndarray
        Held-out residuals and the measured force of the tested trials.
    noise_N2 : (n_trials,) ndarray
        Each trial's lead-in noise power.
    level : (n_trials,) ndarray of int
        Each trial's sE level index.
    sE_levels : sequence of float
        The sE of each level index (names in the output).
    nu, n_lead : float, int
        As for :func:`gap_test`.

    Returns
    -------
    GapTest or None
        :func:`gap_test`'s answer on the level means (one row per level with at least two
        repeats, noise ``mean(N) / n``); None with fewer than three such levels.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> x = np.sin(np.linspace(0, 60, 800))
    >>> lev = np.repeat(np.arange(8), 3)
    >>> dev = rng.normal(0, 0.1, (24, 1)) * x            # each repeat's own gain error
    >>> dev -= np.repeat(dev.reshape(8, 3, -1).mean(1), 3, axis=0)   # predicted from others
    >>> noise = rng.normal(0, 0.01, (24, 800))
    >>> ref = np.tile(x, (24, 1))
    >>> common_test(dev + noise, np.full(24, 1e-4), ref, lev, range(8), 0.5, 300).significant
    False
    >>> common_test(dev + noise + 0.05 * x ** 2, np.full(24, 1e-4), ref, lev, range(8), 0.5,
    ...             300).significant
    True
    """
    rows, refs, noise, names = [], [], [], []
    for j in np.unique(level):
        m = (level == j) & np.isfinite(noise_N2) & (noise_N2 > 0)
        n = int(m.sum())
        if n < 2:
            continue
        rows.append(resid[m].mean(axis=0))
        refs.append(reference[m].mean(axis=0))
        noise.append(float(np.mean(noise_N2[m])) / n)
        names.append(f"sE={float(list(sE_levels)[int(j)]):g}")
    if len(rows) < 3:
        return None
    return gap_test(np.vstack(rows), np.asarray(noise), np.vstack(refs), nu, nu, n_lead,
                    z_crit=z_crit, min_beyond_noise_pct=min_beyond_noise_pct, names=names)


def split_misfit(per_trial: GapTest, common: GapTest | None, min_common_share: float = 0.05
                 ) -> MisfitSplit:
    """The misfit beyond noise split into its common and trial-to-trial parts.

    Parameters
    ----------
    per_trial, common : GapTest
        :func:`gap_test` on the trials and :func:`common_test` on the level means.
    min_common_share : float
        The common part counts only when it is at least this share of the trial-to-trial
        part (NRMSE ratio): the scatter itself leaves a little in the repeats' mean, since
        the response depends non-linearly on wn and zeta (second order in the scatter:
        about 1-2 % of a 10 % trial-to-trial part).

    Returns
    -------
    MisfitSplit
        ``systematic_pct`` and ``trial_to_trial_pct`` (% of the response, beyond noise),
        ``systematic_significant`` and ``within_scatter`` (the per-trial test is
        significant, the common part is not).
    """
    total = per_trial.beyond_noise_pct_typical or 0.0
    if common is None:
        return MisfitSplit(systematic_pct=None, trial_to_trial_pct=None, within_scatter=False,
                           systematic_significant=None)
    sysm = common.beyond_noise_pct_typical or 0.0
    t2t = math.sqrt(max(total ** 2 - sysm ** 2, 0.0))
    sig = bool(common.significant and sysm >= min_common_share * t2t)
    return MisfitSplit(systematic_pct=sysm, trial_to_trial_pct=t2t,
                       within_scatter=bool(per_trial.significant and not sig),
                       systematic_significant=sig)


def gap_fatigue(diag) -> FatigueResult:
    """Fatigue from each trial's gain relative to the nominal model fitted on all trials
    (see module): cumulative stimulation at the window's centre, the session's total taken
    as the last window's end.

    The in-sample fit is used, not the held-out prediction: a repeat predicted from the
    others compares its gain with theirs only, which stretches a trend by ``n / (n - 1)``.
    """
    d = diag.data
    r, _, ref = predict(diag.nominal_full, d)
    pred = ref - r
    num = np.sum(pred * ref, axis=1)
    den = np.sum(pred * pred, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(den > 0, num / den, np.nan)
    c = d.cum_stim_s + 0.5 * d.chirp_s
    total = float(np.max(d.cum_stim_s)) + d.chirp_s if len(c) else float("nan")
    return fit_fatigue(g, d.level, c, total_stim_s=total, source="gain of each trial")


@dataclass
class GapVerdict:
    """The verdict of a diagnosis (:func:`assess`).

    Read as attributes; ``verdict["key"]`` and ``verdict.get("key")`` still work for callers
    written against the former dict.

    Attributes
    ----------
    verdict : str
        ``none``, ``effect``, ``pair``, ``likely``, ``unexplained`` or ``muscle_twin``.
    label : str or None
        The effect (pair) named (for ``likely`` the candidate of best evidence: its
        evidence in ``verdict["likely"]``).
    remaining, nominal_gap : dict
        The final and the nominal model's gap: beyond noise (``beyond_noise_pct_typical``),
        its common part (``systematic_pct``) and trial-to-trial part
        (``trial_to_trial_pct``), significance, where.
    sentence : str
        The verdict in words.
    not_named : str or None
        A candidate that fitted a gap within noise or trial-to-trial variability.
    repeat_scatter_pct : float
        Scatter between repeats without a model (NRMSE %; ``noise_floor_nrmse_pct``).
    fatigue : FatigueResult or None
        The session's fatigue from the held-out gains.
    """

    verdict: str
    label: str | None
    remaining: dict
    nominal_gap: dict
    sentence: str
    not_named: str | None = None
    repeat_scatter_pct: float = float("nan")
    fatigue: FatigueResult | None = None
    extra: dict = field(default_factory=dict)

    def __getitem__(self, key: str):
        if key in {f.name for f in fields(self)}:
            return getattr(self, key)
        return self.extra[key]

    def __contains__(self, key: object) -> bool:
        return key in self.as_dict()

    def keys(self):
        return self.as_dict().keys()

    def get(self, key: str, default=None):
        try:
            return self[key]
        except KeyError:
            return default

    def as_dict(self) -> dict:
        """Plain JSON-able form (the report's ``verdict`` part)."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        out["fatigue"] = self.fatigue.as_dict() if self.fatigue is not None else None
        out.update(self.extra)
        return out


def decide(nominal_significant: bool, kind: str, remaining_significant: bool) -> str:
    """The verdict from three facts (see module).

    Parameters
    ----------
    nominal_significant : bool
        The nominal model's held-out gap is significant.
    kind : {"none", "effect", "pair", "muscle_twin"}
        What the candidate search supports.
    remaining_significant : bool
        What the final model leaves is significant (for ``none`` the nominal's).

    Examples
    --------
    >>> decide(False, "effect", False), decide(True, "none", True), decide(True, "pair", True)
    ('none', 'unexplained', 'pair')
    >>> decide(True, "muscle_twin", False)
    'muscle_twin'
    """
    if kind not in ("none", "effect", "pair", "muscle_twin"):
        raise ValueError(f"kind = {kind!r}: use 'none', 'effect', 'pair' or 'muscle_twin'")
    if not nominal_significant and not remaining_significant:
        return "none"
    if kind == "none":
        return "unexplained"
    return kind if nominal_significant else "none"


def _scatter_words(fig: dict, scatter_pct: float | None) -> str:
    between = (f"; repeats of one sE differ by {scatter_pct:.2f} % of the response without "
               "any model" if scatter_pct is not None and math.isfinite(scatter_pct) else "")
    return (f"trial-to-trial variability, not a model gap: the part common to the repeats "
            f"of each sE, which a better model could capture, is "
            f"{fig.get('systematic_pct') or 0.0:.2f} % (not significant), the part that differs "
            f"between repeats {fig.get('trial_to_trial_pct') or 0.0:.2f} %{between}")


def _likely_sentence(lk: Likely, nom: float, min_shrink_pct: float = 10.0) -> str:
    words = effect_words(lk.label)
    parts = (f"{lk.trial_to_trial_pct:.2f} % of the response differs between repeats, "
             f"{lk.systematic_pct or 0.0:.2f} % is common to them"
             if lk.trial_to_trial_pct is not None else "the repeats differ by more than "
             "the gap")
    if lk.more_repeats is None:
        decide_ = ("the held-out repeats do not yet favour it trial by trial: more repeats "
                   "of each sE are needed to decide")
    elif lk.more_repeats == 0:
        decide_ = (f"its held-out improvement is already consistent trial by trial (z = "
                   f"{lk.z_heldout:.1f}), only small beside the scatter")
    else:
        decide_ = (f"about {lk.more_repeats} more repeat{'s' if lk.more_repeats > 1 else ''} "
                   f"of each sE would decide (the held-out improvement is at z = "
                   f"{lk.z_heldout:.1f} trial by trial)")
    return (f"Likely {words}, not separable from scatter: the nominal model misses "
            f"{nom:.2f} % of the response beyond noise (significant), and {lk.label} has the "
            f"best evidence of the candidates (dIC {lk.delta_ic:.0f} against the nominal "
            f"model), but it shrinks the held-out NRMSE by only {lk.shrink_pct:.1f} % "
            f"({lk.nominal_nrmse_pct:.3g} -> {lk.heldout_nrmse_pct:.3g} %, short of "
            f"{min_shrink_pct:g} %) because trial-to-trial scatter dominates the held-out "
            f"error ({parts}); {decide_}.")


def sentence(verdict: str, label: str | None, nominal: dict, remaining: dict,
             scatter_pct: float | None = None, *, likely: Likely | None = None,
             muscle_floor_multiple: float = 3.0, muscle_to_floor: float | None = None,
             min_shrink_pct: float = 10.0, unit: str = "N") -> str:
    """The verdict in one or two sentences a physiologist understands (``unit``: the
    session's, N or N m).

    ``likely``: the candidate of :func:`likely_candidate` (verdict ``likely``).
    ``muscle_to_floor``: the muscle twin's held-out NRMSE over the noise floor; "the
    remainder is muscle physics" only within ``muscle_floor_multiple`` of it."""
    rem = remaining.get("beyond_noise_pct_typical") or 0.0
    nom = nominal.get("beyond_noise_pct_typical") or 0.0
    where = remaining.get("where_summary") or ""
    conc = remaining.get("concentrated_in") or nominal.get("concentrated_in") or []
    steps = {s["trial"]: s for s in (remaining.get("where") or {}).get("baseline_steps", [])
             if s["share_of_excess_pct"] >= 80}
    tail = ""
    if conc:
        tail = (f" The largest part of the misfit sits in trial(s) {', '.join(map(str, conc))}"
                "; the verdict does not rest on them")
        explained = [c for c in conc if c in steps]
        if explained:
            tail += "; " + ", ".join(
                f"{c} has a baseline step of {steps[c]['height_N']:+.2f} {unit} at "
                f"{steps[c]['t_s']:.1f} s into the chirp" for c in explained)
        if len(explained) < len(conc):
            tail += " - check those trials for a voluntary contraction or an artefact"
        tail += "."
    if verdict == "none" and nominal.get("within_scatter"):
        return ("The nominal second-order model predicts held-out repeats as well as their "
                f"trial-to-trial variability allows: what it misses beyond sensor noise, "
                f"{nom:.2f} % of the response, is {_scatter_words(nominal, scatter_pct)}. No "
                "unmodelled effect is needed." + tail)
    if verdict == "none":
        return ("The nominal second-order model predicts held-out repeats as well as the "
                f"measurement noise allows (what it misses beyond noise, {nom:.2f} % of the "
                "response, is not significant): no unmodelled effect is needed." + tail)
    if verdict == "likely" and likely is not None:
        return _likely_sentence(likely, nom, min_shrink_pct) + tail
    if verdict == "unexplained":
        common = nominal.get("systematic_pct")
        split = (f"; {common:.2f} % common to the repeats of each sE, "
                 f"{nominal.get('trial_to_trial_pct') or 0.0:.2f} % differing between them"
                 if common is not None else "")
        return ("The nominal model misses part of the response "
                f"({nom:.2f} % of the response beyond noise, significant{split}), and none of the "
                f"{_count_words(len(CANDIDATES))} candidate effects, alone or in pairs, explains "
                "it: something else is at "
                f"work{(' - ' + where) if where else ''}." + tail)
    if verdict == "muscle_twin":
        close = muscle_to_floor is None or muscle_to_floor <= muscle_floor_multiple
        lead = ("The remainder is muscle physics" if close else
                f"The muscle twin is the best model here but not the whole story: it leaves "
                f"{muscle_to_floor:.1f}x the noise floor between repeats (muscle physics is "
                f"claimed only within {muscle_floor_multiple:g}x)")
        text = (lead + ": the second-order template (with the best "
                "library effects) leaves a significant gap, and the physiological twin (two "
                "Hill-type muscles with recruitment, activation dynamics and force-dependent "
                "stiffness and damping, one parameter set for every sE) predicts held-out "
                f"repeats better: what it misses beyond noise is {rem:.2f} % of the response "
                f"(nominal {nom:.2f} %)")
        if remaining.get("significant"):
            text += (f", still significant{(' - ' + where) if where else ''}: the muscle "
                     "model is not the whole story either.")
        elif remaining.get("within_scatter"):
            text += f", which is {_scatter_words(remaining, scatter_pct)}."
        else:
            text += ", which is within noise."
        return text + tail
    words = effect_words(label or "")
    text = (f"Adding {words} explains the gap: what the model misses beyond noise falls from "
            f"{nom:.2f} % to {rem:.2f} % of the response")
    if remaining.get("significant"):
        text += (f", but that remainder is still significant{(' - ' + where) if where else ''}"
                 f": {words.split(' (')[0]} is only part of the story.")
    elif remaining.get("within_scatter"):
        text += f", which is {_scatter_words(remaining, scatter_pct)}."
    else:
        text += ", which is within noise."
    return text + tail


def _ratio_rows(resid: np.ndarray, noise_N2: np.ndarray) -> np.ndarray:
    return np.mean(resid ** 2, axis=1) / noise_N2


def where(diag, resid: np.ndarray, components: list[dict], harmonics: dict | None
          ) -> ResidualWhere:
    """Where a held-out residual exceeds the noise: by sE, chirp band, trial position; its
    narrow-band components and harmonics; and a one-line summary.

    Returns
    -------
    ResidualWhere
        Empty parts and an empty summary with fewer than three trials with a measurable
        lead-in noise.
    """
    d = diag.data
    ok = diag.tested & np.isfinite(d.steady_noise_N2) & (d.steady_noise_N2 > 0) \
        if d.steady_noise_N2 is not None else np.zeros(d.n_trials, bool)
    out: dict = {"sE": [], "chirp_band": [], "trial_position": {}, "narrow_band": components,
                 "harmonics": harmonics}
    if ok.sum() < 3:
        return ResidualWhere(narrow_band=components, harmonics=harmonics)
    N = d.steady_noise_N2
    ratio = _ratio_rows(resid[ok], N[ok])
    lev = d.level[ok]
    for j, sE in enumerate(d.sE_levels):
        m = lev == j
        if m.any():
            out["sE"].append({"sE": float(sE), "ratio_to_noise": float(np.median(ratio[m])),
                              "n_trials": int(m.sum())})
    edges = diag.settings.bands_Hz
    f = d.f_inst_Hz
    mean_N = float(np.mean(N[ok]))
    for lo, hi in pairwise(edges):
        m = (f >= lo) & (f < hi if hi < edges[-1] else f <= hi)
        if m.any():
            out["chirp_band"].append({"f_lo_Hz": lo, "f_hi_Hz": hi, "ratio_to_noise":
                                      float(np.mean(resid[ok][:, m] ** 2)) / mean_N})
    order = d.order[ok]
    thirds = np.array_split(np.argsort(order), 3)
    out["trial_position"] = {
        "ratio_to_noise_by_third": [float(np.median(ratio[t])) if len(t) else None
                                    for t in thirds],
        "correlation_with_order": float(np.corrcoef(order, np.log(ratio))[0, 1])
        if len(ratio) >= 3 and np.std(np.log(ratio)) > 0 else None}
    return ResidualWhere(sE=tuple(out["sE"]), chirp_band=tuple(out["chirp_band"]),
                         trial_position=out["trial_position"], narrow_band=components,
                         harmonics=harmonics, summary=_summary(out))


def baseline_steps(diag, resid: np.ndarray) -> list[dict]:
    """Baseline steps inside held-out trials (a jump at an unknown time): trial, time after
    the chirp's start, height, and how much of the trial's misfit beyond noise it carries."""
    d = diag.data
    ok = np.flatnonzero(diag.tested)
    if len(ok) == 0:
        return []
    Q = nuisance_basis(d.t_eval_s, 0.0)
    r = resid[ok]
    out = []
    for st in find_steps(r, Q, d.subset(ok)):
        i, u = st.row, st.column
        a = float(r[i] @ u)
        after = r[i] - a * u
        N = d.steady_noise_N2[ok[i]] if d.steady_noise_N2 is not None else 0.0
        ex_before = max(float(np.mean(r[i] ** 2)) - N, 1e-30)
        ex_after = max(float(np.mean(after ** 2)) - N, 0.0)
        k, height = st.sample, a * st.height_per_unit_N
        out.append({"trial": d.trials[ok[i]].name, "t_s": float(d.t_eval_s[k]),
                    "height_N": height,
                    "share_of_excess_pct": 100.0 * (1 - ex_after / ex_before)})
    return out


def _summary(w: dict) -> str:
    parts = []
    bands = w["chirp_band"]
    if bands:
        vals = np.array([b["ratio_to_noise"] for b in bands])
        k = int(np.argmax(vals))
        if vals[k] > 1.5 and vals[k] > 1.5 * np.median(vals):
            parts.append(f"mostly in the {bands[k]['f_lo_Hz']:g}-{bands[k]['f_hi_Hz']:g} Hz "
                         "part of the chirp")
    levels = w["sE"]
    if levels:
        vals = np.array([s["ratio_to_noise"] for s in levels])
        k = int(np.argmax(vals))
        if vals[k] > 1.5 and vals[k] > 1.5 * np.median(vals):
            parts.append(f"largest at sE = {levels[k]['sE']:g}")
    tp = w["trial_position"]
    c = tp.get("correlation_with_order")
    if c is not None and abs(c) > 0.5:
        parts.append("growing through the session" if c > 0 else "largest early in the session")
    for comp in w["narrow_band"]:
        if comp["significant"]:
            rest = comp.get("at_rest")
            parts.append(f"an oscillation near {comp['f_Hz']:.1f} Hz "
                         f"({comp['width_Hz']:.1f} Hz wide"
                         + (", present at rest too: not a response to the stimulation"
                            if rest is not None and rest > 2 else "") + ")")
    h = w.get("harmonics") or {}
    if h.get("excess"):
        parts.append(f"distortion at {' and '.join(h['excess'])} the chirp frequency "
                     "(a non-linearity)")
    return "; ".join(parts)


def _harmonics(diag, res) -> dict | None:
    d = diag.data
    ok = diag.tested
    args = (d.phase_eval_rad, d.f_inst_Hz, d.t_eval_s)
    try:
        hm = local_harmonics(diag.reference[ok], *args, orders=(1,))
        hr = local_harmonics(res.heldout_resid[ok], *args, orders=HARMONIC_ORDERS)
    except (ValueError, IndexError, FloatingPointError):
        return None
    fund = np.abs(hm.amplitude[:, :, 0])
    rel = np.abs(hr.amplitude) / fund[:, :, None]
    h = {f"{o:g}f": float(np.nanmedian(100 * rel[:, :, k]))
         for k, o in enumerate(HARMONIC_ORDERS)}
    ref = h.get("1.5f", float("nan"))
    excess = [k for k in ("2f", "3f") if k in h and np.isfinite(ref) and h[k] > 2.5 * ref
              and h[k] > 0.5]
    return {"median_residual_pct": h, "excess": excess}


def _held_out_tests(diag, resid: np.ndarray) -> tuple[dict, list]:
    """The significance tests of one held-out residual (every trial of ``diag.tested``):
    broadband (:func:`gap_test`), narrow-band (:func:`narrow_band`) and the split into
    the part common to the repeats and trial-to-trial scatter; with ``significant_total``
    (broadband beyond the scatter, or a narrow-band component). Returns (tests,
    narrow-band components)."""
    d = diag.data
    s = diag.settings
    if d.steady_N is not None and d.steady_N.shape[1] >= 16:
        nu = effective_fraction(d.steady_N, d.fs_eval_Hz, d.settings.lowpass_Hz)
        n_lead = int(d.steady_N.shape[1])
    else:
        nu, n_lead = 2 * d.settings.lowpass_Hz / d.fs_eval_Hz, 1
    ok = diag.tested
    noise = d.steady_noise_N2 if d.steady_noise_N2 is not None else np.full(d.n_trials, np.nan)
    names = [d.trials[i].name for i in np.flatnonzero(ok)]
    band_top = min(d.settings.lowpass_Hz, d.fs_eval_Hz / 2)
    rest = d.steady_N[ok] if d.steady_N is not None else None
    r = resid[ok]
    gt = gap_test(r, noise[ok], diag.reference[ok], nu, nu, n_lead, z_crit=s.significance_z,
                  min_beyond_noise_pct=s.min_beyond_noise_pct, names=names)
    comps = narrow_band(r, diag.reference[ok], rest, d.fs_eval_Hz, band_top,
                        f_min_Hz=d.chirp_f0_Hz, min_beyond_noise_pct=s.min_beyond_noise_pct)
    common = common_test(r, noise[ok], diag.reference[ok], d.level[ok], d.sE_levels, nu,
                         n_lead, z_crit=s.significance_z,
                         min_beyond_noise_pct=s.min_beyond_noise_pct)
    split = split_misfit(gt, common, s.min_common_share)
    t = {**gt.to_dict(), **split.to_dict()}
    t["narrow_band_significant"] = any(c["significant"] for c in comps)
    broadband = bool(t["significant"] and not t["within_scatter"])
    t["significant_total"] = bool(broadband or t["narrow_band_significant"])
    return t, comps


def nominal_settles(diag) -> tuple[bool, tuple[dict, list]]:
    """Whether the nominal model's held-out gap alone settles the verdict as ``none``, with
    nothing in any trial for the candidates to show.

    When the nominal gap is significant neither broadband (whatever the scatter between
    repeats) nor in a narrow band, :func:`decide` answers ``none`` for every candidate
    search: with no candidate supported the nominal gap is judged by ``significant_total``,
    with one supported by ``significant or narrow_band_significant``, and both are false.
    The candidates need not be fitted then (``GapSettings.skip_settled``), unless the gap
    is concentrated in a few trials (``concentrated_in``): the verdict stays ``none``, but
    what the candidates make of those trials (a baseline step found in one) is reported.

    ``diag`` needs ``data``, ``settings``, ``tested``, ``reference`` and ``nominal``
    (a :class:`Diagnosis` under construction will do). Returns (settled, the nominal's
    tests as :func:`assess` computes them, to be handed to it).
    """
    tests = _held_out_tests(diag, diag.nominal.heldout_resid)
    t = tests[0]
    settled = not (t["significant"] or t["narrow_band_significant"] or t["concentrated_in"])
    return settled, tests


def assess(diag, muscle=None, nominal_tests: tuple[dict, list] | None = None) -> GapVerdict:
    """Verdict, the nominal gap and the remaining gap of a diagnosis (see module).

    ``muscle``: a supported :class:`nmsid.analysis.muscle.candidate.MuscleResult`, which then
    replaces the template's final model as the answer. ``nominal_tests``: the nominal's
    tests when computed already (:func:`nominal_settles`, on the same diagnosis)."""

    def test(res):
        return _held_out_tests(diag, res.heldout_resid)

    nom, nom_comps = nominal_tests if nominal_tests is not None else test(diag.nominal)
    final = diag.best_pair or diag.best
    kind = "none" if final is None else ("pair" if diag.best_pair is not None else "effect")
    if muscle is not None:
        final, kind = muscle, "muscle_twin"
    if final is None:
        rem, comps, res = nom, nom_comps, diag.nominal
    else:
        (rem, comps), res = test(final), final
    # a supported candidate explains (part of) what differs between repeats (fatigue,
    # drift move each repeat differently): the nominal gap is then judged against noise
    nominal_sig = nom["significant_total"] if kind == "none" else \
        bool(nom["significant"] or nom["narrow_band_significant"])
    verdict = decide(nominal_sig, kind, rem["significant_total"])
    likely = likely_candidate(diag, nom) if verdict == "unexplained" else None
    if likely is not None:
        verdict = "likely"
    if verdict == "none":      # nothing named: what remains is the nominal model's gap
        rem, comps, res = nom, nom_comps, diag.nominal
    w = where(diag, res.heldout_resid, comps, _harmonics(diag, res)).to_dict()
    w["baseline_steps"] = baseline_steps(diag, diag.nominal.heldout_resid)
    rem = dict(rem)
    rem["where"] = w
    rem["where_summary"] = w["summary"]
    label = final.label if final is not None else None
    remaining = {"beyond_noise_pct": rem["beyond_noise_pct"],
                 "beyond_noise_pct_typical": rem["beyond_noise_pct_typical"],
                 "significant": rem["significant_total"],
                 "broadband_significant": bool(rem["significant"]
                                               and not rem["within_scatter"]),
                 "systematic_pct": rem["systematic_pct"],
                 "trial_to_trial_pct": rem["trial_to_trial_pct"],
                 "within_scatter": rem["within_scatter"],
                 "systematic_significant": rem["systematic_significant"],
                 "narrow_band_significant": rem["narrow_band_significant"],
                 "median_ratio_to_noise": rem["median_ratio"], "z": rem["z"],
                 "concentrated_in": rem["concentrated_in"],
                 "concentrated_share_pct": rem.get("concentrated_share_pct"),
                 "n_trials": rem["n_trials"], "where": w}
    nominal = {k: nom.get(k) for k in ("beyond_noise_pct", "beyond_noise_pct_typical",
                                        "median_ratio", "z", "significant_total",
                                        "concentrated_in", "concentrated_share_pct",
                                        "n_trials", "systematic_pct", "trial_to_trial_pct",
                                        "systematic_significant", "within_scatter")}
    nominal["significant"] = nominal.pop("significant_total")
    if verdict == "none" and final is not None:
        within = ("trial-to-trial variability" if nom.get("within_scatter") else "noise")
        note = (f"{label} would fit, but the gap it would explain is within {within} "
                f"(nominal gap beyond noise {nom['beyond_noise_pct_typical'] or 0:.2f} %, "
                "not significant): not named")
    else:
        note = None
    scatter_pct = getattr(diag, "noise_floor_nrmse_pct", None)
    if likely is not None:
        label = likely.label
    text = sentence(verdict, label, nom, dict(rem, where_summary=w["summary"], where=w,
                                              significant=rem["significant_total"]),
                    scatter_pct, likely=likely,
                    muscle_floor_multiple=getattr(diag.settings, "muscle_floor_multiple", 3.0),
                    muscle_to_floor=_muscle_to_floor(diag, muscle),
                    min_shrink_pct=diag.settings.min_shrink_pct,
                    unit=getattr(diag.data, "measured", ("", "", "N"))[2])
    try:
        fatigue = gap_fatigue(diag)
    except (ValueError, FloatingPointError):
        fatigue = None
    named = verdict in ("effect", "pair", "muscle_twin", "likely")
    fatigue_first = False
    if fatigue is not None and fatigue.significant:
        fatigue_first = fatigue_is_largest(diag, label if named else None)
        if named and "fatigue" in (label or ""):
            text += f" Measured from each trial's gain: {fatigue.sentence()}."
        elif fatigue_first:
            text = (f"Fatigue is the largest single effect here: {fatigue.sentence()} "
                    "(each trial's gain against the stimulation given before it, the "
                    "levels' own gains aside; its candidate shrinks the held-out NRMSE "
                    "most of all). " + text)
        else:
            text += (f" Beside it, the session shows {fatigue.sentence()}: each trial's gain "
                     "against the stimulation given before it, the levels' own gains aside.")
    out = GapVerdict(verdict=verdict, label=label if named else None, remaining=remaining,
                     nominal_gap=nominal, sentence=text, not_named=note,
                     repeat_scatter_pct=float(scatter_pct) if scatter_pct is not None
                     else float("nan"), fatigue=fatigue)
    if likely is not None:
        out.extra["likely"] = likely.to_dict()
    out.extra["fatigue_named"] = bool(fatigue_first)
    qc = qc_basis(diag)
    out.extra["qc"] = qc
    if qc["n_excluded"]:
        out.sentence = qc_words(qc) + out.sentence
    return out


def fatigue_is_largest(diag, named_label: str | None) -> bool:
    """Fatigue is named first when the verdict does not name it, yet its candidate
    shrinks the held-out NRMSE more than any other single candidate (and at all): on a
    physics participant the muscle's own non-linearity keeps every candidate short of
    support, but the gain lost through the session is still the largest thing found."""
    if named_label and "fatigue" in named_label:
        return False
    cands = [r for r in getattr(diag, "candidates", []) or []
             if math.isfinite(r.shrink_pct)]
    if not cands:
        return False
    top = max(cands, key=lambda r: r.shrink_pct)
    return bool(top.label == "fatigue" and top.shrink_pct > 0)


def _reason_head(reason: str) -> str:
    """A QC reason's kind: its text up to the first ':', ';' or '(' (what groups them)."""
    for sep in (":", ";", "("):
        reason = reason.split(sep)[0]
    return reason.strip() or "excluded"


def qc_basis(diag) -> dict:
    """What the verdict rests on after quality control: trials used, excluded and why.

    Returns
    -------
    dict
        ``n_used``, ``n_excluded``, ``n_completed`` (used + excluded), ``share_used``,
        ``min_share`` (``GapSettings.min_trial_share``), ``partial`` (the verdict rests on
        fewer than that share of the completed trials) and ``reasons`` (count per kind).
    """
    d = diag.data
    excluded = dict(getattr(d, "excluded", {}) or {})
    n_used = int(d.n_trials)
    n_ex = len(excluded)
    total = n_used + n_ex
    share = n_used / total if total else float("nan")
    min_share = float(getattr(diag.settings, "min_trial_share", 0.75))
    reasons: dict[str, int] = {}
    for r in excluded.values():
        head = _reason_head(str(r))
        reasons[head] = reasons.get(head, 0) + 1
    return {"n_used": n_used, "n_excluded": n_ex, "n_completed": total,
            "share_used": share, "min_share": min_share,
            "partial": bool(total and share < min_share), "reasons": reasons,
            "excluded": sorted(excluded)}


def qc_words(qc: dict) -> str:
    """The sentence's opening when quality control excluded trials."""
    kinds = sorted(qc["reasons"].items(), key=lambda kv: -kv[1])
    why = "; ".join(f"{n} {k}" for k, n in kinds[:3]) + ("; ..." if len(kinds) > 3 else "")
    names = ", ".join(qc["excluded"][:4]) + (", ..." if len(qc["excluded"]) > 4 else "")
    if qc["partial"]:
        return (f"[Partial verdict: quality control excluded {qc['n_excluded']} of "
                f"{qc['n_completed']} trials ({why}: {names}); the verdict rests on only "
                f"{qc['n_used']} ({100 * qc['share_used']:.0f} %, below the "
                f"{100 * qc['min_share']:.0f} % a full verdict needs) and may change "
                "with them.] ")
    return (f"[Quality control excluded {qc['n_excluded']} of {qc['n_completed']} trials "
            f"({why}: {names}); the verdict rests on the other {qc['n_used']}.] ")


@dataclass(frozen=True)
class Likely:
    """A candidate that wins on evidence but that the held-out test cannot separate from
    trial-to-trial scatter (:func:`likely_candidate`).

    Attributes
    ----------
    label : str
        The candidate (effect name).
    delta_ic : float
        Its information criterion against the nominal model (training trials).
    shrink_pct : float
        Its held-out NRMSE's relative shrink (below ``min_shrink_pct``).
    heldout_nrmse_pct, nominal_nrmse_pct : float
    z_heldout : float
        The paired held-out improvement (residual power per trial, nominal minus
        candidate) in standard errors.
    more_repeats : int or None
        Repeats of each sE to add for that improvement to reach ``significance_z``
        standard errors (0: it has; None: it does not improve on the held-out trials).
    trial_to_trial_pct, systematic_pct : float or None
        The nominal misfit's parts (:class:`MisfitSplit`).
    """

    label: str
    delta_ic: float
    shrink_pct: float
    heldout_nrmse_pct: float
    nominal_nrmse_pct: float
    z_heldout: float
    more_repeats: int | None
    trial_to_trial_pct: float | None
    systematic_pct: float | None

    def to_dict(self) -> dict:
        """Plain form (the report's ``verdict.likely``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: The paired held-out improvement (in standard errors) a candidate needs to be "likely".
LIKELY_MIN_Z = 1.5


def likely_candidate(diag, nominal_tests: dict) -> Likely | None:
    """The candidate of best evidence when nothing is supported and scatter hides it.

    Conditions: some single candidate has ``dIC < -ic_margin`` (it wins on evidence, on
    the training trials) and predicts the held-out repeats better than the nominal
    model (shrink > 0), but less than ``min_shrink_pct``, and consistently so trial by
    trial (paired ``z >= LIKELY_MIN_Z``: a fatigue trend fitted to random gain scatter
    gains dIC, since the criterion counts samples, not trials, but no held-out trial);
    ``baseline_drift`` is not eligible (it fits each held-out trial's own baseline, so
    its held-out improvement is not a test); and trial-to-trial scatter
    dominates the nominal model's held-out error (its part differing between repeats is
    larger than the part common to them, or the repeats differ by at least half the
    nominal NRMSE without any model). Then the held-out test cannot separate it from
    scatter: the answer is "likely X", never "something else".

    The repeats that would decide: the paired held-out improvement ``d_i`` (residual
    power of the nominal minus the candidate on held-out trial ``i``) is at
    ``z = mean(d) / (sd(d) / sqrt(n))``; ``n (z_crit / z)^2`` trials reach ``z_crit``.
    Among the eligible, the lowest dIC is named.
    """
    s = diag.settings
    cands = [r for r in getattr(diag, "candidates", []) or []
             if r.delta_ic < -s.ic_margin and 0.0 < r.shrink_pct < s.min_shrink_pct
             and math.isfinite(r.heldout_nrmse_pct)
             and not getattr(r.candidate, "fits_baseline", False)]
    if not cands:
        return None
    nom_pct = diag.nominal.heldout_nrmse_pct
    t2t = nominal_tests.get("trial_to_trial_pct")
    sysm = nominal_tests.get("systematic_pct")
    floor = getattr(diag, "noise_floor_nrmse_pct", float("nan"))
    scatter_dominates = bool((t2t is not None and sysm is not None and t2t > sysm)
                             or (math.isfinite(floor) and floor >= 0.5 * nom_pct))
    if not scatter_dominates:
        return None
    ok = diag.tested
    p_nom = np.mean(diag.nominal.heldout_resid[ok] ** 2, axis=1)
    scored = []
    for r in cands:
        d = p_nom - np.mean(r.heldout_resid[ok] ** 2, axis=1)
        n = len(d)
        sd = float(np.std(d, ddof=1)) if n > 1 else float("nan")
        z = float(np.mean(d)) / (sd / math.sqrt(n)) if n > 1 and sd > 0 else float("nan")
        if math.isfinite(z) and z >= LIKELY_MIN_Z:
            scored.append((r, z, n))
    if not scored:
        return None
    best, z, n = min(scored, key=lambda item: item[0].delta_ic)
    n_levels = max(len(np.unique(diag.data.level[ok])), 1)
    need = n * (s.significance_z / z) ** 2
    more: int | None = max(0, math.ceil(need / n_levels - n / n_levels))
    return Likely(label=best.label, delta_ic=float(best.delta_ic),
                  shrink_pct=float(best.shrink_pct),
                  heldout_nrmse_pct=float(best.heldout_nrmse_pct),
                  nominal_nrmse_pct=float(nom_pct), z_heldout=z, more_repeats=more,
                  trial_to_trial_pct=t2t, systematic_pct=sysm)


def _muscle_to_floor(diag, muscle) -> float | None:
    """The muscle twin's held-out NRMSE over the repeat-to-repeat noise floor."""
    floor = getattr(diag, "noise_floor_nrmse_pct", float("nan"))
    if muscle is None or not (math.isfinite(floor) and floor > 0):
        return None
    return float(muscle.heldout_nrmse_pct) / floor
