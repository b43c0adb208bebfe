"""Identify the second-order model of each sE level of a session.

Two entry points, both safe to call from a GUI thread or a headless run:

* :func:`identify_level` - the completed repeats of one sE (the GUI calls it after each
  level); aborted or broken repeats are skipped with a reason;
* :func:`identify_session` - every level of a session file, one row per sE plus a list of
  human-readable problems. Nothing in a level's data stops the other levels.

Both use :mod:`nmsid.analysis.preprocess` and :mod:`nmsid.analysis.second_order`, which the gap
diagnosis reuses.
"""

from __future__ import annotations

import logging
import math
import os
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.data_bounds import check_session_data
from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.fatigue import FatigueResult, cumulative_stimulation_s, fit_fatigue
from nmsid.analysis.input_timing import fit_level
from nmsid.analysis.preprocess import LevelData, TrialSignals
from nmsid.analysis.qc import SessionQC, assess_level, assess_session
from nmsid.analysis.qc.decide import EXCLUDED, REPAIRED, LevelQC
from nmsid.analysis.scatter import ScatterResult, fit_trials, summarise
from nmsid.analysis.second_order import SecondOrderFit
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.joints import recorded_quantity
from nmsid.protocols.reprs import counted, html_repr, number_span, short_repr, to_dataframe
from nmsid.protocols.session_file import read_session

logger = logging.getLogger(__name__)


@dataclass
class LevelResult:
    """Identification of one sE level."""

    sE: float
    fit: SecondOrderFit | None
    data: LevelData | None
    n_trials: int
    trial_names: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    qc: LevelQC | None = None
    """The quality control's verdicts on this level's trials (None when QC is off)."""
    used_trials: list = field(default_factory=list, repr=False)
    """The trials the fit used (the repeats each fitted on its own for the scatter)."""

    @property
    def ok(self) -> bool:
        """True when parameters were estimated (converged or not: see ``fit.converged``)."""
        return self.fit is not None

    def to_dict(self, participant: str = "") -> dict:
        """The ``parameters.csv`` row of this level (NaN where nothing was estimated)."""
        f = self.fit
        nan = float("nan")
        return {
            "participant": participant, "sE": self.sE,
            "Kp": f.Kp if f else nan, "wn_rad_s": f.wn_rad_s if f else nan,
            "zeta": f.zeta if f else nan, "fit_pct": f.fit_pct if f else nan,
            "n_trials": self.n_trials,
            "n_repeats_used": self.n_trials,
            "n_repeats_excluded": (sum(v.decision == EXCLUDED for v in self.qc.verdicts)
                                   if self.qc else 0),
            "qc_flag": self.qc.flag if self.qc else "",
            "Kp_se": f.Kp_se if f else nan, "wn_se": f.wn_se if f else nan,
            "zeta_se": f.zeta_se if f else nan,
            "converged": bool(f.converged) if f else False,
            "resid_whiteness_pass": bool(f.residual_tests.whiteness_pass) if f else False,
            "resid_independence_pass": bool(f.residual_tests.independence_pass) if f else False,
            "baseline_N": self.data.baseline_N if self.data else nan,
        }

    def __repr__(self) -> str:
        f = self.fit
        fitted = ("not identified" if f is None else
                  f"Kp {f.Kp:.4g}, wn {f.wn_rad_s:.4g} rad/s, zeta {f.zeta:.4g}, "
                  f"fit {f.fit_pct:.1f} %" + ("" if f.converged else " (not converged)"))
        return short_repr("LevelResult", f"sE {self.sE:g}", counted(self.n_trials, "trial"),
                          fitted, f"QC {self.qc.flag}" if self.qc and self.qc.flag else "",
                          counted(len(self.problems), "problem") if self.problems else "")

    _repr_html_ = html_repr


@dataclass
class SessionResult:
    """Identification of every sE level of one session."""

    participant: str
    source: str
    levels: list[LevelResult]
    problems: list[str]
    settings: IdentificationSettings
    calibration: dict = field(default_factory=dict)
    qc: SessionQC | None = None
    """The quality control's verdict on every trial (None when QC is off)."""
    scatter: ScatterResult | None = None
    """Trial-to-trial scatter of Kp, wn, zeta per sE and pooled
    (:mod:`nmsid.analysis.scatter`; None when not computed)."""
    fatigue: FatigueResult | None = None
    """The gain lost with accumulated stimulation over the session
    (:mod:`nmsid.analysis.fatigue`; None when not computed)."""
    joint: str = "elbow"
    """The joint the session recorded (root attribute ``joint``; none: the elbow)."""
    quantity: str = "force"
    """What ``force_N`` holds: ``force`` (N) or ``torque`` (N m) (``docs/joints.md``)."""
    unit: str = "N"
    """The unit of the measured quantity, of Kp (per unit rE) and of the baseline."""

    def rows(self) -> list[dict]:
        """One dict per sE level: the ``parameters.csv`` row (:meth:`LevelResult.to_dict`)."""
        return [lv.to_dict(self.participant) for lv in self.levels]

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        fits = [lv.fit.fit_pct for lv in self.levels if lv.fit is not None]
        return short_repr(
            "SessionResult", self.participant,
            f"{len(fits)}/{len(self.levels)} sE levels identified "
            f"{number_span(lv.sE for lv in self.levels)}".rstrip(),
            f"fit {number_span(fits, '.1f')} %" if fits else "",
            counted(len(self.problems), "problem") if self.problems else "", str(self.source))

    _repr_html_ = html_repr

    def parameter(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(sE, values) of one parameter over the levels that were identified."""
        pairs = [(lv.sE, getattr(lv.fit, name)) for lv in self.levels if lv.fit is not None]
        if not pairs:
            return np.empty(0), np.empty(0)
        x, y = zip(*pairs, strict=True)
        return np.asarray(x, dtype=float), np.asarray(y, dtype=float)


def _describe(trial) -> str:
    return f"trial {trial.name or '?'} (sE={trial.sE:g}, repeat {trial.repeat})"


def usable_trials(trials, settings: IdentificationSettings | None = None):
    """Split trials into those that can be averaged and reasons for the others.

    Returns
    -------
    usable : list of Trial
    problems : list of str
        One message per skipped trial, naming it and saying why.
    """
    s = settings or IdentificationSettings()
    usable, problems = [], []
    for tr in trials:
        if not tr.completed:
            reason = tr.abort_reason or "no reason recorded"
            problems.append(f"{_describe(tr)} was aborted ({reason}); skipped")
            continue
        bad = {}
        for key in ("force_N", "rE"):
            arr = np.asarray(getattr(tr, key), dtype=float)
            n_bad = int(np.sum(~np.isfinite(arr)))
            if n_bad:
                bad[key] = n_bad
        if bad:
            what = ", ".join(f"{v} non-finite sample(s) in {k}" for k, v in bad.items())
            problems.append(f"{_describe(tr)} has {what}; skipped")
            continue
        start = s.window_start_s if s.window_start_s is not None else tr.steady_s
        if tr.n_samples / tr.fs_Hz <= start + 1.0:
            problems.append(f"{_describe(tr)} is only {tr.n_samples / tr.fs_Hz:.2f} s long, "
                            f"ending before the window (from {start:g} s) has 1 s of data; "
                            "skipped")
            continue
        usable.append(tr)
    return usable, problems


def identify_level(trials, settings: IdentificationSettings | None = None,
                   qc: LevelQC | None = None, *,
                   cache: TrialSignals | None = None) -> LevelResult:
    """Identify the second-order model from the repeats of one sE level.

    Parameters
    ----------
    trials : sequence of protocols.session_file.Trial
        The trials run at this sE (aborted ones are skipped and reported).
    settings : IdentificationSettings, optional
    qc : LevelQC, optional
        The quality control's verdicts (computed here when ``settings.qc`` and not given):
        only the trials it keeps are averaged and fitted, repaired ones with their
        repaired force.
    cache : TrialSignals, optional
        Each repeat filtered once for the session's fits (:func:`identify_session`).

    Returns
    -------
    LevelResult
        ``fit`` is None when nothing could be estimated; ``problems`` says why, and notes
        a single repeat, a fit that did not converge, or failed residual tests.

    Raises
    ------
    ValueError
        If ``trials`` is empty or mixes sE values (a programming error of the caller).
    """
    s = settings or IdentificationSettings()
    trials = list(trials)
    if not trials:
        raise ValueError("identify_level needs at least one trial")
    levels = {round(float(t.sE), 9) for t in trials}
    if len(levels) > 1:
        raise ValueError(f"identify_level got trials of several sE values {sorted(levels)}; "
                         "pass the trials of one level")
    sE = float(trials[0].sE)
    qc_notes: list[str] = []
    if s.qc:
        qc = qc if qc is not None else assess_level(trials, s.qc_settings)
        trials = [t for t in trials if not t.completed] + list(qc.kept)
        for v in qc.verdicts:
            if v.decision in (EXCLUDED, REPAIRED):
                qc_notes.append(f"trial {v.trial} (sE={v.sE:g}, repeat {v.repeat}) "
                                f"{v.decision} by QC: {'; '.join(v.reasons)}")
        if qc.flag:
            qc_notes.append(f"sE={sE:g}: QC: {qc.flag}")
    else:
        qc = None
    usable, problems = usable_trials(trials, s)
    problems = qc_notes + problems
    names = [t.name for t in usable]
    if not usable:
        problems.append(f"sE={sE:g}: no usable trial; level not identified")
        return LevelResult(sE, None, None, 0, names, problems, qc)
    if len(usable) == 1:
        problems.append(f"sE={sE:g}: only one usable repeat ({usable[0].name}); "
                        "parameters rest on a single trial")
    lengths = {t.n_samples for t in usable}
    if len(lengths) > 1:
        problems.append(f"sE={sE:g}: repeats differ in length ({sorted(lengths)} samples); "
                        "averaged over the common part")
    try:
        # preprocessing and fit under the rig's input-timing model (estimated by default)
        data, fit, _timing = fit_level(usable, s, cache=cache)
    except (IdentificationError, np.linalg.LinAlgError, ArithmeticError) as exc:
        problems.append(f"sE={sE:g}: {exc}; level not identified")
        return LevelResult(sE, None, None, len(usable), names, problems, qc)
    if not fit.converged:
        problems.append(f"sE={sE:g}: fit did not converge ({fit.message}); parameters "
                        "reported but flagged, and left out of the model selection")
    for note in fit.notes:
        problems.append(f"sE={sE:g}: {note}")
    if not math.isfinite(fit.fit_pct) or fit.fit_pct < 50:
        problems.append(f"sE={sE:g}: poor fit ({fit.fit_pct:.1f} %); check the force signal")
    return LevelResult(sE, fit, data, len(usable), names, problems, qc, used_trials=usable)


#: The datasets the identification needs; the others (currents, wrench, sync) are not read
#: when ``read_session`` can skip them.
NEEDED_DATASETS = ("rE", "force_N")
#: sE (the sum of the two EAAs) lies in (0, 1] (session-file contract); a trial outside it
#: is excluded and reported, so it cannot stretch the curves or the twin's range.
SE_RANGE = (0.0, 1.0)


def _read_for_identification(path, read_session):
    """Read a session, loading only rE and force_N when the reader supports it."""
    import inspect
    try:
        accepts = "datasets" in inspect.signature(read_session).parameters
    except (TypeError, ValueError):
        accepts = False
    if accepts:
        return read_session(path, datasets=NEEDED_DATASETS)
    return read_session(path)


def identify_session(session, settings: IdentificationSettings | None = None,
                     progress=None, *, trial_scatter: bool = True) -> SessionResult:
    """Identify every sE level of a session.

    Parameters
    ----------
    session : path-like or protocols.session_file.Session
        A session file (read with ``read_session``) or an already-read session.
    settings : IdentificationSettings, optional
    progress : callable(sE, LevelResult), optional
        Called after each level (e.g. to update a GUI).
    trial_scatter : bool
        Also fit every repeat on its own: the trial-to-trial scatter
        (:mod:`nmsid.analysis.scatter`) and the within-session fatigue
        (:mod:`nmsid.analysis.fatigue`) of the result; a significant fatigue is a problem.

    Returns
    -------
    SessionResult

    Raises
    ------
    protocols.session_file.SessionFileError
        If the file cannot be read as a session (the message names the file and item).
    """

    s = settings or IdentificationSettings()
    if isinstance(session, (str, os.PathLike)):
        session = _read_for_identification(session, read_session)
    check_session_data(session)
    if (getattr(session, "attrs", None) or {}).get("session_kind") == "cocontraction":
        raise IdentificationError(f"{session.path}: a co-contraction sweep (sE steps at a "
                                  "fixed rE, no chirp): there is no dynamics to identify "
                                  "(docs/joints.md)")
    problems: list[str] = []
    groups: dict[float, list] = {}
    outside = []
    for tr in session.trials:
        if not (math.isfinite(float(tr.sE)) and SE_RANGE[0] < float(tr.sE) <= SE_RANGE[1]):
            outside.append(tr)  # sE is an activation sum: outside (0, 1] it is not data
            continue
        groups.setdefault(round(float(tr.sE), 9), []).append(tr)
    if outside:
        problems.append(f"{session.path}: {len(outside)} trial(s) excluded: sE outside "
                        f"({SE_RANGE[0]:g}, {SE_RANGE[1]:g}] ("
                        + ", ".join(f"{getattr(t, 'name', '?')} sE {float(t.sE):g}"
                                    for t in outside[:5])
                        + (", ..." if len(outside) > 5 else "") + ")")
    if not groups:
        problems.append(f"{session.path}: the session holds no trials; nothing to identify")
    completed = Counter(round(float(t.sE), 9) for t in session.trials
                        if t.completed and id(t) not in {id(o) for o in outside})
    config = session.config if isinstance(session.config, dict) else {}
    protocol: dict = config["protocol"] if isinstance(config.get("protocol"), dict) else config
    planned = protocol.get("sE_levels")
    planned_repeats = protocol.get("repeats")
    expected = int(planned_repeats) if isinstance(planned_repeats, int) and planned_repeats > 0 \
        else (max(completed.values()) if completed else 0)
    session_qc = assess_session(session, s.qc_settings) if s.qc else None
    level_qc = {round(lq.sE, 9): lq for lq in session_qc.levels} if session_qc else {}
    levels = []
    cache = TrialSignals(s)     # each repeat filtered once for the level and scatter fits
    for key in sorted(groups):
        lv = identify_level(groups[key], s, qc=level_qc.get(key), cache=cache)
        n_done = completed.get(key, 0)
        if expected > 1 and n_done < expected:
            lv.problems.insert(0, f"sE={key:g}: {n_done} of {expected} repeats completed")
        levels.append(lv)
        problems.extend(lv.problems)
        if progress is not None:
            progress(lv.sE, lv)
    if isinstance(planned, list):
        missing = sorted({round(float(x), 9) for x in planned} - set(groups))
        for m in missing:
            problems.append(f"sE={m:g}: planned but no trial in the file (session incomplete?)")
    scatter, fatigue = (session_scatter(session.trials, levels, s, cache=cache)
                        if trial_scatter else (None, None))
    if fatigue is not None and fatigue.significant:
        problems.append(f"{fatigue.sentence()}: each sE's parameters average repeats taken "
                        "at different fatigue (see the scatter and docs/identification.md)")
    for p in problems:
        logger.info("%s: %s", session.participant, p)
    cal = session.calibration
    cal_dict = {k: float(getattr(cal, k)) for k in
                ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")}
    joint, quantity, unit = recorded_quantity(getattr(session, "attrs", {}) or {})
    return SessionResult(participant=session.participant, source=str(session.path),
                         levels=levels, problems=problems, settings=s, calibration=cal_dict,
                         qc=session_qc, scatter=scatter, fatigue=fatigue, joint=joint,
                         quantity=quantity, unit=unit)


def session_scatter(all_trials, levels: list[LevelResult],
                    settings: IdentificationSettings | None = None, *,
                    cache: TrialSignals | None = None
                    ) -> tuple[ScatterResult, FatigueResult]:
    """Each used repeat fitted on its own; the fatigue those fits show; their scatter.

    Parameters
    ----------
    all_trials : sequence of Trial
        Every trial of the session in file order (their durations give the cumulative
        stimulation).
    levels : list of LevelResult
        The identified levels (their used trials and fits).
    settings : IdentificationSettings, optional
    cache : TrialSignals, optional
        The repeats as filtered for the level fits (:func:`identify_session`).

    Returns
    -------
    scatter : ScatterResult
        Kp corrected for the fatigue when it is significant.
    fatigue : FatigueResult
        From the per-trial Kp.
    """
    centre, total = cumulative_stimulation_s(all_trials)
    cum = {id(t): float(c) for t, c in zip(all_trials, centre, strict=True)}
    ok = [lv for lv in levels if lv.fit is not None and lv.data is not None]
    fits, notes = fit_trials([lv.used_trials for lv in ok], [(lv.data, lv.fit) for lv in ok],
                             cum, settings, cache=cache)
    fatigue = fit_fatigue([f.Kp for f in fits], [round(f.sE, 9) for f in fits],
                          [f.cum_stim_s for f in fits], total_stim_s=total,
                          source="per-trial Kp")
    return summarise(fits, fatigue, notes), fatigue
