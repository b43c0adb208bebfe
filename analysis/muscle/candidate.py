"""The physiological twin as a candidate of the gap diagnosis.

Tried only when the template's best answer (nominal, effect or pair) still leaves a
significant gap. Scored exactly like the library's candidates: fitted on each fold's
training trials (one parameter set for every sE), held-out repeats predicted, held-out
NRMSE and ``dIC = N_eff ln(RSS / RSS_nominal) + 2 dk`` on the training trials with the same
effective-sample fraction ``nu``. ``dk`` is its 18 parameters minus the nominal model's
three per sE level and its timing correction: the muscle twin has *fewer* parameters than
the per-level template. It is *supported* when, like a pair against its single effect, it
beats the nominal model (``dIC < -ic_margin``, held-out shrink >= ``min_shrink_pct``) and
also the template's final model (held-out NRMSE ``min_shrink_pct`` % below it and ``dIC``
lower by ``ic_margin``).

The fold twins are one damped Gauss-Newton step from the fit on every trial (the twin the report
gives) towards the optimum of each fold's training trials
(:func:`nmsid.analysis.muscle.fit.subset_refit`): the left-out repeats' influence removed to
first order, at the cost of one batched simulation for all folds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.gap.models import nuisance_basis
from nmsid.analysis.muscle.errors import MuscleFitError
from nmsid.analysis.muscle.fit import (
    FoldStep,
    MuscleFit,
    MuscleFitSettings,
    fit_muscle,
    subset_refit,
)

log = logging.getLogger(__name__)

LABEL = "muscle_twin"


@dataclass
class MuscleResult:
    """The muscle twin scored on one session (the fields the report reads of a candidate)."""

    fold_fits: list[FoldStep]
    full: MuscleFit
    heldout_resid: np.ndarray
    heldout_nrmse_pct: float
    insample_nrmse_pct: float
    delta_ic: float = 0.0
    delta_k: int = 0
    shrink_pct: float = 0.0
    shrink_vs_template_pct: float = 0.0
    supported: bool = False
    fit_s: float = 0.0
    cpu_s: float = 0.0
    """CPU time of this process spent on the muscle twin (fit_s is wall time)."""
    params: Mapping[str, float] = field(default_factory=dict)
    """The fitted parameters by name (:attr:`MuscleFit.params`)."""
    label: str = LABEL
    converged: bool = True
    """False when the fit or a fold's prediction did not give a finite residual (the
    simulation overflowed, the solver failed): then nothing of it is scored, ``supported``
    is False and :attr:`note` says why; the report gives it a row that says so."""
    note: str = ""
    """Why the fit was not scored (empty when it was)."""
    with_fatigue: bool = False
    """Fitted with the session's fatigue (``MuscleFitSettings.trial_gain``)."""


def not_converged(note: str, full: MuscleFit | None, shape: tuple[int, int],
                  fit_s: float, cpu_s: float) -> MuscleResult:
    """The result of a muscle-twin fit that did not converge: every figure NaN, not
    supported, ``note`` saying what failed."""
    nan = float("nan")
    return MuscleResult(fold_fits=[], full=full,  # type: ignore[arg-type]
                        heldout_resid=np.full(shape, np.nan), heldout_nrmse_pct=nan,
                        insample_nrmse_pct=nan, delta_ic=nan, shrink_pct=nan,
                        shrink_vs_template_pct=nan, supported=False, fit_s=fit_s,
                        cpu_s=cpu_s, params=full.params if full is not None else {},
                        converged=False, note=note)


def _nrmse(r, ref):
    return 100.0 * float(np.sqrt(np.sum(r ** 2) / np.sum(ref ** 2)))


def score_muscle(run, nominal, final, settings, *, fit_settings: MuscleFitSettings | None
                 = None) -> MuscleResult:
    """Fit and score the muscle twin on the folds of a diagnosis.

    Parameters
    ----------
    run : analysis.gap.diagnose._Runner
        Folds, training and test data, ``nu`` and the reference.
    nominal, final : CandidateResult
        The nominal model and the template's final model (the nominal one when nothing
        was supported).
    settings : GapSettings
    fit_settings : MuscleFitSettings, optional

    Returns
    -------
    MuscleResult
    """
    t0 = time.perf_counter()
    c0 = time.process_time()
    fs = fit_settings or MuscleFitSettings()
    d = run.data
    try:
        return _score(run, nominal, final, settings, fs, t0, c0)
    except (FloatingPointError, OverflowError, ArithmeticError, np.linalg.LinAlgError,
            ValueError) as exc:
        # a model that overflows or a solver that fails on this session: a row that says
        # so, never a crash (MuscleFitError, a setting that does not suit, is a
        # GapInputError and not caught here)
        if isinstance(exc, MuscleFitError):
            raise
        log.warning("muscle twin not fitted: %s", exc)
        return not_converged(f"the fit did not converge ({type(exc).__name__}: {exc})",
                             None, d.y_N.shape, time.perf_counter() - t0,
                             time.process_time() - c0)


def _score(run, nominal, final, settings, fs: MuscleFitSettings, t0: float, c0: float
           ) -> MuscleResult:
    d = run.data
    full = fit_muscle(d, fs, label="all trials")
    if not (np.isfinite(full.rss) and np.all(np.isfinite(full.theta))):
        return not_converged("the fit on all trials did not converge (its residual is not "
                             "finite: the simulation overflowed)", full, d.y_N.shape,
                             time.perf_counter() - t0, time.process_time() - c0)
    # each fold's twin: one damped Gauss-Newton step from the fit on every trial towards the
    # optimum of its training trials (fit.subset_refit: one batched simulation of
    # every candidate step on every trial gives the held-out and training residuals)
    t1 = time.perf_counter()
    thetas, R = subset_refit(full, d, [fold.train for fold in run.folds], fs)
    resid = np.full_like(d.y_N, np.nan)
    n_ev = R.shape[2]
    resid[:, n_ev:] = 0.0          # the evaluation samples past the fit grid, if any
    fits = []
    ins_num = ins_den = 0.0
    per_fold = (time.perf_counter() - t1) / len(run.folds)
    for k, fold in enumerate(run.folds):
        resid[fold.test, :n_ev] = R[k][fold.test]
        r_tr = R[k][fold.train]
        fits.append(FoldStep(theta=thetas[k], rss=float(np.sum(r_tr ** 2)),
                             n_samples=int(r_tr.size), elapsed_s=per_fold))
        ins_num += fits[-1].rss
        tr = run.train[k]
        ins_den += float(np.sum(((tr.y_N - (tr.y_N @ _Q(tr)) @ _Q(tr).T)) ** 2))
    tested = ~np.isnan(resid[:, 0])
    if not np.all(np.isfinite(resid[tested])) or not np.isfinite(ins_num):
        return not_converged("the held-out predictions did not converge (a fold's twin "
                             "overflowed)", full, d.y_N.shape, time.perf_counter() - t0,
                             time.process_time() - c0)
    res = MuscleResult(fold_fits=fits, full=full, heldout_resid=resid,
                       heldout_nrmse_pct=_nrmse(resid[tested], run.reference[tested]),
                       insample_nrmse_pct=100.0 * np.sqrt(ins_num / ins_den),
                       params=full.params)
    n_levels = len(d.sE_levels)
    # the session's fatigue, when the fit carries it, counts as its two parameters
    dk = len(full.theta) - (3 * n_levels + 1) + (2 if fs.trial_gain is not None else 0)
    dic = [run.nu * f.n_samples * np.log(f.rss / nf.rss) + 2 * dk
           for f, nf in zip(fits, nominal.fold_fits, strict=True)]
    res.delta_ic = float(np.mean(dic))
    res.delta_k = int(dk)
    res.shrink_pct = 100.0 * (1 - res.heldout_nrmse_pct / nominal.heldout_nrmse_pct)
    res.shrink_vs_template_pct = 100.0 * (1 - res.heldout_nrmse_pct / final.heldout_nrmse_pct)
    final_dic = final.delta_ic if final is not nominal else 0.0
    res.supported = bool(res.delta_ic < -settings.ic_margin
                         and res.shrink_pct >= settings.min_shrink_pct
                         and res.shrink_vs_template_pct >= settings.min_shrink_pct
                         and res.delta_ic < final_dic - settings.ic_margin)
    res.with_fatigue = fs.trial_gain is not None
    res.fit_s = time.perf_counter() - t0
    res.cpu_s = time.process_time() - c0
    log.info("muscle twin: held-out NRMSE %.3f %% (nominal %.3f %%, template %.3f %%), "
             "dIC %.1f, %.1f s", res.heldout_nrmse_pct, nominal.heldout_nrmse_pct,
             final.heldout_nrmse_pct, res.delta_ic, res.fit_s)
    return res


def _Q(data):
    return nuisance_basis(data.t_eval_s, 0.0)
