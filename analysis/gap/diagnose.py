"""Which unmodelled effect explains the sim-to-real gap, and how far adding it shrinks it.

For one session: every candidate (and the nominal model) is fitted on the training trials
of each cross-validation fold (:mod:`nmsid.analysis.gap.crossval`) and predicts the held-out
repeat. Candidates are ranked by their held-out NRMSE and by an information criterion
computed with the *effective* number of independent samples.

Effective samples. The force is low-passed at 25 Hz and evaluated at 125 Hz, and a model's
misfit is smooth, so neighbouring residual samples are far from independent. With ``N``
residual samples, ``N_eff = N nu`` where ``nu = 1 / (1 + 2 sum_k rho_k)`` from the
residual's autocorrelation (summed while it stays above 0.05, the "initial positive
sequence"), capped at the analysis bandwidth ``2 B / fs_eval``. ``nu`` is that of the
measurement noise in the steady lead-in (no model involved), the same for the nominal
model, every candidate and every pair, so all are compared on one basis.
The criterion is ``dIC = N_eff ln(RSS_aug / RSS_nom) + 2 dk`` on the training trials
(averaged over folds); ``dk`` counts the shared parameters, and for ``baseline_drift`` the
baseline coefficients of every trial.

Decision. A candidate is *supported* when ``dIC < -ic_margin`` and its held-out NRMSE is
at least ``min_shrink_pct`` % below the nominal's. The winner is the supported candidate
with the lowest held-out NRMSE; when two are within ``tie_pct`` % of each other, the lower
``dIC`` decides. ``none`` when nothing is supported.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.gap.crossval import Fold, repeat_folds
from nmsid.analysis.gap.data import GapData
from nmsid.analysis.gap.errors import GapInputError
from nmsid.analysis.gap.fit import ModelFit, fit_model, predict
from nmsid.analysis.gap.models import NOMINAL, Candidate, candidate, n_drift_columns, nuisance_basis
from nmsid.analysis.gap.samples import effective_fraction
from nmsid.analysis.gap.verdict import GapVerdict, assess, nominal_settles
from nmsid.protocols.effects import CANDIDATES, Effect

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GapSettings:
    """Settings of the diagnosis (defaults documented in ``docs/gap.md``)."""

    candidates: tuple[Effect, ...] = field(default_factory=lambda: tuple(CANDIDATES))
    drift_corners_Hz: tuple[float, ...] = (0.1, 0.2, 0.35, 0.5)
    """Baseline bandwidths tried for ``baseline_drift`` (below the 1 Hz chirp start)."""
    ic_margin: float = 10.0
    """dIC must be below minus this (about 'very strong' evidence on the AIC scale)."""
    min_shrink_pct: float = 10.0
    """Held-out NRMSE must fall by at least this share (relative) for an effect to count."""
    tie_pct: float = 3.0
    """Held-out NRMSEs within this relative difference are a tie, settled by dIC."""
    try_pairs: bool = True
    """Also try the winner together with each other effect (screened on the first fold,
    cross-validated when the second effect adds beyond the winner)."""
    max_iter: int = 25
    bands_Hz: tuple[float, ...] = (1.0, 1.5, 2.2, 3.3, 5.0, 7.5, 10.0)
    significance_z: float = 3.0
    """A gap is significant when the median log ratio of held-out residual power to
    lead-in noise power exceeds this many standard errors (``analysis.gap.verdict``)."""
    min_beyond_noise_pct: float = 0.1
    """... and the gap beyond noise is at least this (NRMSE points of the response): a
    twin 99.9 % right is not wrong in any way a physiologist would act on."""
    min_common_share: float = 0.05
    """The part of the misfit common to the repeats of each sE is a model gap only when it
    is at least this share (NRMSE ratio) of the part that differs between repeats; below,
    the misfit is trial-to-trial variability (``analysis.gap.verdict``)."""
    deviation_edges: tuple[float, ...] = (-0.5, -0.25, 0.0, 0.25, 0.5)
    skip_settled: bool = True
    """Fit no candidate when the nominal model's held-out gap is already within noise
    (significant neither broadband nor in a narrow band): no candidate can change the
    verdict ``none`` then (:func:`nmsid.analysis.gap.verdict.nominal_settles`), and the
    report says the candidates were not fitted. False fits and ranks them anyway."""
    try_muscle: bool = True
    """When the template's answer leaves a significant gap, also try the physiological
    twin (:mod:`nmsid.analysis.muscle.candidate`)."""
    min_trial_share: float = 0.75
    """A verdict on fewer than this share of the completed trials (quality control
    excluded the rest) is marked partial in its sentence and the report's ``qc``."""
    muscle_floor_multiple: float = 3.0
    """The verdict says "the remainder is muscle physics" only when the muscle twin's
    held-out NRMSE is within this multiple of the noise floor between repeats."""
    muscle_fs_Hz: float = 100.0
    """Simulation rate of the muscle twin's fit (reduced from the 200 Hz fit rate)."""
    progress: bool = False
    """Progress lines on stderr for the long muscle-twin fit."""


@dataclass
class CandidateResult:
    """One model family scored on one session."""

    candidate: Candidate
    fold_fits: list[ModelFit]
    heldout_resid: np.ndarray
    """(n_trials, n_eval) held-out residual (NaN rows: trials never held out)."""
    heldout_nrmse_pct: float
    insample_nrmse_pct: float
    delta_ic: float = 0.0
    delta_k: int = 0
    nu: float = float("nan")
    shrink_pct: float = 0.0
    supported: bool = False
    params: dict = field(default_factory=dict)
    fit_s: float = 0.0

    @property
    def label(self) -> str:
        return self.candidate.label


@dataclass
class Diagnosis:
    """Everything the report needs about one session."""

    data: GapData
    settings: GapSettings
    folds: list[Fold]
    reference: np.ndarray
    """(n_trials, n_eval) measured force with offset and trend removed (NRMSE reference)."""
    tested: np.ndarray
    """(n_trials,) bool: trial was held out in some fold."""
    nominal: CandidateResult
    candidates: list[CandidateResult]
    pairs: list[CandidateResult]
    best: CandidateResult | None
    best_pair: CandidateResult | None
    full_fit: ModelFit
    """The winner (or nominal) fitted on all trials: what the twin file holds."""
    nominal_full: ModelFit
    noise_floor_nrmse_pct: float
    sensor_floor_nrmse_pct: float = float("nan")
    """Noise in the steady lead-in (no stimulation change, no model involved) as an NRMSE
    of the held-out trials: the part of any model's error that is measurement noise."""
    elapsed_s: float = 0.0
    assessment: GapVerdict | dict = field(default_factory=dict)
    """Verdict, nominal and remaining gap (``analysis.gap.verdict.assess``)."""
    candidates_skipped: str | None = None
    """Why no candidate was fitted (``GapSettings.skip_settled``), or None when they were."""
    not_named: CandidateResult | None = None
    """A candidate (or pair) that was supported on a gap within noise, hence not named."""
    muscle_tried: object | None = None
    """The physiological twin's result (``analysis.muscle.candidate.MuscleResult``) when it
    was tried (the template left a significant gap), supported or not."""
    muscle: object | None = None
    """... the same when it is supported: the verdict is then ``muscle_twin``."""

    def excess_pct(self, nrmse_pct: float) -> float:
        """The gap beyond measurement noise: ``sqrt(NRMSE^2 - sensor floor^2)``."""
        f = self.sensor_floor_nrmse_pct
        if not np.isfinite(f):
            return nrmse_pct
        return float(np.sqrt(max(nrmse_pct ** 2 - f ** 2, 0.0)))

    @property
    def best_effect(self) -> Effect:
        return self.best.candidate.effect if self.best is not None else Effect.NONE


def _nrmse(resid: np.ndarray, ref: np.ndarray) -> float:
    den = float(np.sum(ref ** 2))
    return 100.0 * float(np.sqrt(np.sum(resid ** 2) / den)) if den > 0 else float("nan")


def noise_floor_pct(data: GapData, reference: np.ndarray) -> float:
    """Repeat-to-repeat scatter: half the variance of differences between repeats of the
    same sE (after offset and trend), as an NRMSE. No model can predict a held-out repeat
    better than this on average."""
    num, den = 0.0, 0.0
    for j in np.unique(data.level):
        rows = np.flatnonzero(data.level == j)
        if len(rows) < 2:
            continue
        for a in range(len(rows)):
            for b in range(a + 1, len(rows)):
                d = reference[rows[a]] - reference[rows[b]]
                num += 0.5 * float(np.sum(d ** 2))
                den += 0.5 * float(np.sum(reference[rows[a]] ** 2 + reference[rows[b]] ** 2))
    return 100.0 * np.sqrt(num / den) if den > 0 else float("nan")


class _Runner:
    #: the held-out reference signal (set by :func:`diagnose`)
    reference: np.ndarray

    def __init__(self, data: GapData, settings: GapSettings):
        self.data = data
        self.s = settings
        self.folds = repeat_folds(data)
        if not self.folds:
            raise GapInputError(
                f"{data.path}: cross-validation needs at least two repeats of some sE "
                f"level; found repeats {sorted(set(data.repeat.tolist()))}")
        self.train = [data.subset(f.train) for f in self.folds]
        self.test = [data.subset(f.test) for f in self.folds]
        self.bandwidth = data.settings.lowpass_Hz
        # one effective-sample basis for every model, single or pair: that of the noise
        # itself (the steady lead-in, no model involved); a model's own residual would
        # give each model a different N_eff and tilt the comparison
        if data.steady_N is not None and data.steady_N.shape[1] >= 16:
            self.nu = effective_fraction(data.steady_N, data.fs_eval_Hz, self.bandwidth)
        else:
            self.nu = min(1.0, 2 * self.bandwidth / data.fs_eval_Hz)

    def score(self, cand: Candidate, fits: list[ModelFit], nominal: CandidateResult | None
              ) -> CandidateResult:
        d = self.data
        resid = np.full_like(d.y_N, np.nan)
        ins_num = ins_den = 0.0
        for fold, tr, te, fit in zip(self.folds, self.train, self.test, fits, strict=True):
            r, _, _ = predict(fit, te)
            resid[fold.test] = r
            ins_num += fit.rss
            ins_den += float(np.sum(_ref_of(tr) ** 2))
        tested = ~np.isnan(resid[:, 0])
        res = CandidateResult(
            candidate=cand, fold_fits=fits, heldout_resid=resid,
            heldout_nrmse_pct=_nrmse(resid[tested], self.reference[tested]),
            insample_nrmse_pct=100.0 * np.sqrt(ins_num / ins_den),
            params=_mean_params(fits))
        if nominal is not None:
            dic, dk, nus = [], [], []
            for fit, nom_fit, tr in zip(fits, nominal.fold_fits, self.train, strict=True):
                nu = self.nu
                k = cand.n_shared()
                if cand.fits_baseline:
                    k += n_drift_columns(d.t_eval_s, fit.corner_Hz) * tr.n_trials
                    k += 2 * fit.n_steps      # a step's time and height
                n_eff = nu * fit.n_samples
                dic.append(n_eff * np.log(fit.rss / nom_fit.rss) + 2 * k)
                dk.append(k)
                nus.append(nu)
            res.delta_ic = float(np.mean(dic))
            res.delta_k = int(round(np.mean(dk)))
            res.nu = float(np.mean(nus))
            res.shrink_pct = 100.0 * (1 - res.heldout_nrmse_pct / nominal.heldout_nrmse_pct)
            res.supported = bool(res.delta_ic < -self.s.ic_margin
                                 and res.shrink_pct >= self.s.min_shrink_pct)
        return res

    def drift_fits(self, nominal_fits: list[ModelFit], cand: Candidate) -> list[ModelFit]:
        """Per fold: the baseline bandwidth with the lowest training IC."""
        out = []
        d = self.data
        for tr, nom in zip(self.train, nominal_fits, strict=True):
            best, best_ic = nom, 0.0
            first: ModelFit | None = None
            for fc in self.s.drift_corners_Hz:
                # the baseline is nearly orthogonal to the 1-10 Hz response: a few
                # iterations from the nominal fit settle the dynamics
                fit = fit_model(tr, cand, start=nom, corner_Hz=fc, max_iter=4)
                first = first or fit
                nu = self.nu
                k = n_drift_columns(d.t_eval_s, fc) * tr.n_trials + 2 * fit.n_steps
                ic = nu * fit.n_samples * np.log(fit.rss / nom.rss) + 2 * k
                if ic < best_ic:
                    best, best_ic = fit, ic
            if best is nom and first is not None:
                # nothing better: the smallest bandwidth (scored as is), the fit just made
                # with the same start and settings
                best = first
            out.append(best)
        return out


def _ref_of(data: GapData) -> np.ndarray:
    Q = nuisance_basis(data.t_eval_s, 0.0)
    return data.y_N - (data.y_N @ Q) @ Q.T


def _mean_params(fits: list[ModelFit]) -> dict:
    keys = fits[0].params.keys()
    return {k: float(np.mean([f.params[k] for f in fits])) for k in keys}


def diagnose(data: GapData, settings: GapSettings | None = None) -> Diagnosis:
    """Run the whole diagnosis of one session.

    Parameters
    ----------
    data : GapData
        From :func:`nmsid.analysis.gap.data.load_session`.
    settings : GapSettings, optional

    Returns
    -------
    Diagnosis
    """
    t0 = time.perf_counter()
    s = settings or GapSettings()
    run = _Runner(data, s)
    run.reference = _ref_of(data)
    nom_fits = [fit_model(tr, NOMINAL, max_iter=s.max_iter) for tr in run.train]
    nominal = run.score(NOMINAL, nom_fits, None)
    tested = ~np.isnan(nominal.heldout_resid[:, 0])
    nominal_tests = None
    skipped = None
    if s.skip_settled:
        early = _Early(data=data, settings=s, tested=tested, reference=run.reference,
                       nominal=nominal)
        settled, nominal_tests = nominal_settles(early)
        if settled:
            t = nominal_tests[0]
            if t.get("z") is None:   # too few trials with a lead-in noise to test
                skipped = ("no candidate fitted: the nominal model's held-out gap could not "
                           f"be tested against noise ({t.get('note') or 'no test'}), so no "
                           "candidate could change the verdict")
            else:
                skipped = (f"no candidate fitted: the nominal model's held-out gap is within "
                           f"noise (z = {t['z']:.2f} < {s.significance_z:g}, beyond noise "
                           f"{t.get('beyond_noise_pct_typical') or 0:.2f} % of the response; "
                           "no narrow-band component), so no candidate could change the "
                           "verdict")
    results = []
    for e in (s.candidates if skipped is None else ()):
        t1 = time.perf_counter()
        cand = candidate(e)
        if cand.fits_baseline:  # its bandwidth is chosen on a grid, not by the solver
            fits = run.drift_fits(nom_fits, cand)
        else:
            fits = [fit_model(tr, cand, start=nf, max_iter=s.max_iter)
                    for tr, nf in zip(run.train, nom_fits, strict=True)]
        res = run.score(cand, fits, nominal)
        res.fit_s = time.perf_counter() - t1
        log.info("%s: held-out NRMSE %.3f %% (nominal %.3f %%), dIC %.1f, %.1f s",
                 e.value, res.heldout_nrmse_pct, nominal.heldout_nrmse_pct, res.delta_ic,
                 res.fit_s)
        results.append(res)
    best = _choose(results, s)
    pairs: list[CandidateResult] = []
    best_pair = None
    if best is not None and s.try_pairs:
        for other in results:
            if other is best:
                continue
            effs = sorted({best.candidate.effect, other.candidate.effect},
                          key=lambda e: CANDIDATES.index(e))
            cand = candidate(*effs)

            def pair_fit(k, max_iter, other=other, effs=effs, cand=cand):
                p0 = np.concatenate([_fold_p(best, other, e, k) for e in effs]
                                    + [[1e3 * best.candidate.timing_s(
                                        best.fold_fits[k].p_shared)]])
                return fit_model(run.train[k], cand, start=best.fold_fits[k], p_start=p0,
                                 corner_Hz=max(best.fold_fits[k].corner_Hz,
                                               other.fold_fits[k].corner_Hz),
                                 max_iter=max_iter)

            # screen on the first fold: does the second effect add beyond the winner?
            screen = pair_fit(0, 10)
            nu = run.nu
            dk = cand.n_shared() - best.candidate.n_shared()
            if cand.fits_baseline and not best.candidate.fits_baseline:
                dk += n_drift_columns(data.t_eval_s, screen.corner_Hz) * run.train[0].n_trials
            gain = nu * screen.n_samples * np.log(screen.rss / best.fold_fits[0].rss) + 2 * dk
            if not gain < -s.ic_margin:
                continue
            fits = [screen] + [pair_fit(k, s.max_iter) for k in range(1, len(run.train))]
            res = run.score(cand, fits, nominal)
            # a pair must beat the single winner, not only the nominal model
            rel = 100.0 * (1 - res.heldout_nrmse_pct / best.heldout_nrmse_pct)
            res.supported = res.supported and rel >= s.min_shrink_pct and \
                res.delta_ic < best.delta_ic - s.ic_margin
            pairs.append(res)
        good = [p for p in pairs if p.supported]
        best_pair = min(good, key=lambda r: r.heldout_nrmse_pct) if good else None
    final = best_pair or best
    full_cand = final.candidate if final is not None else NOMINAL
    nominal_full = fit_model(data, NOMINAL, max_iter=s.max_iter)
    if final is None:
        full = nominal_full
    else:
        p0 = np.mean([f.p_shared for f in final.fold_fits], axis=0)
        corner = float(np.median([f.corner_Hz for f in final.fold_fits]))
        full = fit_model(data, full_cand, start=nominal_full, p_start=p0, corner_Hz=corner,
                         max_iter=s.max_iter)
    sensor = float("nan")
    if data.steady_noise_N2 is not None and np.any(np.isfinite(data.steady_noise_N2[tested])):
        sensor = 100.0 * float(np.sqrt(np.nanmean(data.steady_noise_N2[tested])
                                       / np.mean(run.reference[tested] ** 2)))
    diag = Diagnosis(data=data, settings=s, folds=run.folds, reference=run.reference,
                     tested=tested, nominal=nominal, candidates=results, pairs=pairs,
                     best=best, best_pair=best_pair, full_fit=full, nominal_full=nominal_full,
                     noise_floor_nrmse_pct=noise_floor_pct(data, run.reference),
                     sensor_floor_nrmse_pct=sensor, candidates_skipped=skipped)
    # the nominal's tests made for the early stop are the ones assess would make
    diag.assessment = assess(diag, nominal_tests=nominal_tests)
    if s.try_muscle and diag.assessment["verdict"] in ("effect", "pair", "unexplained",
                                                       "likely") \
            and diag.assessment["remaining"]["significant"]:
        # lazy: the muscle twin's modules are needed only when the template falls short
        from nmsid.analysis.muscle.candidate import score_muscle
        from nmsid.analysis.muscle.fit import MuscleFitSettings  # lazy, as the line above
        gains = _fatigue_gains(diag)
        mres = score_muscle(run, nominal, final if final is not None else nominal, s,
                            fit_settings=MuscleFitSettings(fs_fit_Hz=s.muscle_fs_Hz,
                                                           progress=s.progress,
                                                           trial_gain=gains))
        diag.muscle_tried = mres
        if mres.supported:
            diag.muscle = mres
            diag.assessment = assess(diag, muscle=mres)
    if diag.assessment["verdict"] == "none" and (best is not None):
        # a candidate fitted a gap that is within noise: not named, the twin stays nominal
        diag.not_named = best_pair or best
        diag.best, diag.best_pair, diag.full_fit = None, None, nominal_full
    diag.elapsed_s = time.perf_counter() - t0
    return diag


def _fatigue_gains(diag: Diagnosis) -> tuple[float, ...] | None:
    """Each trial's gain from the session's significant fatigue (mean 1), for the muscle
    twin's fit; None without significant fatigue (or when the final model fits it)."""
    fat = getattr(diag.assessment, "fatigue", None)
    final = diag.best_pair or diag.best
    if final is not None and "fatigue" in final.label:
        return None
    if fat is None or not fat.significant or not fat.estimated:
        return None
    d = diag.data
    g = np.asarray(fat.gain_at(d.cum_stim_s + 0.5 * d.chirp_s), float)
    if not (np.all(np.isfinite(g)) and np.all(g > 0)):
        return None
    return tuple(float(v) for v in g / np.mean(g))


@dataclass
class _Early:
    """What :func:`nmsid.analysis.gap.verdict.nominal_settles` reads of a diagnosis, before
    the candidates are fitted."""

    data: GapData
    settings: GapSettings
    tested: np.ndarray
    reference: np.ndarray
    nominal: CandidateResult


def _fold_p(best: CandidateResult, other: CandidateResult, effect: Effect, k: int):
    for r in (best, other):
        if r.candidate.effects == (effect,):
            return r.candidate.sub(r.fold_fits[k].p_shared, effect)
    return np.zeros(0)


def _choose(results: list[CandidateResult], s: GapSettings) -> CandidateResult | None:
    good = sorted((r for r in results if r.supported), key=lambda r: r.heldout_nrmse_pct)
    if not good:
        return None
    best = good[0]
    for r in good[1:]:
        if r.heldout_nrmse_pct <= best.heldout_nrmse_pct * (1 + s.tie_pct / 100) and \
                r.delta_ic < best.delta_ic:
            best = r
    return best


def ranking(diag: Diagnosis) -> list[CandidateResult]:
    """Candidates (singles and pairs) by held-out NRMSE, best first."""
    return sorted(diag.candidates + diag.pairs, key=lambda r: r.heldout_nrmse_pct)
