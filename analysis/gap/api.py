"""One call for the whole job: read sessions, diagnose each, write the outputs.

A single session writes its report straight into ``out_dir``; several sessions get one
sub-folder each (named after the file) and a top-level ``gap_report.json`` that lists them
and the effect most of them point to.

The *simulation under test* is by default the nominal twin fitted on the training trials.
With ``twin`` (a twin file, run with its effects on the simulator's virtual participant
with an ideal sensor) or ``sim_session`` (a simulated session, trials matched by sE and
repeat) the 'where' part is also computed for that simulation: every trial is then held
out, since nothing of it was fitted on this session. The candidate search ('which'
and 'how far') always works from the nominal model fitted by cross-validation.
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nmsid.analysis.data_bounds import check_session_data
from nmsid.analysis.gap.data import (
    GAP_DATASETS,
    GapData,
    PreprocessSettings,
    load_session,
    prepare_trials,
)
from nmsid.analysis.gap.diagnose import CandidateResult, Diagnosis, GapSettings, diagnose
from nmsid.analysis.gap.errors import GapInputError
from nmsid.analysis.gap.localize import by_location, frequency_view
from nmsid.analysis.gap.models import NOMINAL, nuisance_basis
from nmsid.analysis.gap.report import json_safe, write_outputs
from nmsid.analysis.qc import assess_session
from nmsid.protocols.reprs import counted, html_repr, short_repr, to_dataframe
from nmsid.protocols.session_file import Session, read_session
from nmsid.protocols.waveforms import currents_mA

log = logging.getLogger(__name__)

__all__ = ["GapSettings", "run_gap", "external_predictions"]


def external_predictions(data: GapData, *, twin=None, sim_session=None,
                         session: Session | None = None) -> np.ndarray:
    """(n_trials, n_eval) force predicted by an external simulation, pre-processed like the
    measurement.

    ``session``: the measured session already read (its rE and sE drive the twin); read
    from ``data.path`` when not given.

    Raises
    ------
    GapInputError
        A trial has no counterpart in the simulated session, or the twin cannot be read.
    """

    if sim_session is not None:
        sim = read_session(sim_session, datasets=GAP_DATASETS)
        table = {(round(t.sE, 6), t.repeat): t for t in sim.trials if t.completed}
        sim_trials = []
        for info in data.trials:  # in the measured file's order
            t = table.get((round(info.sE, 6), info.repeat))
            if t is None:
                raise GapInputError(f"{sim_session}: no completed trial with sE = {info.sE:g}"
                                    f", repeat {info.repeat} to compare with {info.name}")
            sim_trials.append(t)
        sim_data = prepare_trials(sim_trials, path=str(sim_session), settings=data.settings,
                                  timing=data.timing)
        n = min(sim_data.y_N.shape[1], data.y_N.shape[1])
        if n < data.y_N.shape[1]:
            raise GapInputError(f"{sim_session}: simulated trials are shorter than the "
                                "measured ones")
        return sim_data.y_N[:, :n]
    return _twin_predictions(data, twin, session)


def _twin_predictions(data: GapData, twin, session: Session | None = None) -> np.ndarray:
    """Every trial's commanded rE and sE run through the twin (effects included) on the
    simulator's virtual participant with an ideal sensor, in file order (aborted trials
    too: they count for fatigue)."""
    # only with --twin: the simulator (and scipy.signal with it) stays out of the others
    from nmsid.sim_backends.sensor import SensorModel  # lazy, see above
    from nmsid.sim_backends.simulation import ParticipantSimulator  # lazy, see above
    from nmsid.sim_backends.twin import participant_from_twin  # lazy, see above
    try:
        participant = participant_from_twin(str(twin), sensor=SensorModel.ideal(),
                                            snap_calibration=False)
    except (OSError, ValueError) as exc:
        raise GapInputError(f"{twin}: cannot be used as the simulation under test ({exc})"
                            ) from None
    if session is None:
        session = read_session(data.path, datasets=GAP_DATASETS)
    cal = participant.calibration
    sim = ParticipantSimulator(participant, data.fs_raw_Hz)
    by_name = {}
    for t in session.trials:
        I_e, I_f = currents_mA(t.rE, t.sE, cal.Iemin_mA, cal.Iemax_mA, cal.Ifmin_mA,
                               cal.Ifmax_mA)
        by_name[t.name] = _with_force(t, sim.simulate(I_e, I_f).force_N)
    trials = [by_name[info.name] for info in data.trials]
    return prepare_trials(trials, path=str(twin), settings=data.settings,
                          timing=data.timing).y_N


def _with_force(trial, force):
    from dataclasses import replace
    return replace(trial, force_N=np.asarray(force, float))


def _under_test(diag: Diagnosis, pred: np.ndarray, label: str) -> dict:
    d = diag.data
    Q = nuisance_basis(d.t_eval_s, 0.0)
    r = d.y_N - pred
    r = r - (r @ Q) @ Q.T
    res = CandidateResult(candidate=NOMINAL, fold_fits=[], heldout_resid=r,
                          heldout_nrmse_pct=100 * float(np.sqrt(np.sum(r ** 2) /
                                                                np.sum(diag.reference ** 2))),
                          insample_nrmse_pct=float("nan"))
    saved = diag.tested
    diag.tested = np.ones(d.n_trials, dtype=bool)
    try:
        out = {"source": label, "nrmse_pct": res.heldout_nrmse_pct,
               "localization": by_location(diag, res).to_dict(),
               "frequency": frequency_view(diag, res).to_dict()}
    finally:
        diag.tested = saved
    return out


@dataclass(frozen=True)
class GapRun:
    """What :func:`run_gap` wrote.

    Attributes
    ----------
    sessions : list of dict
        Each session's ``gap_report.json`` document, in the order given.
    report : pathlib.Path or None
        The top-level ``gap_report.json`` (a group summary for several sessions); None
        when nothing was kept (``nmsid.diagnose_gap`` without a folder).
    """

    sessions: list[dict]
    report: Path | None

    def rows(self) -> list[dict]:
        """One dict per session: its verdict, the effect it points to and the held-out
        NRMSE before and after adding it (from its ``gap_report.json``)."""
        out = []
        for s in self.sessions:
            h = s.get("heldout") or {}
            out.append({"session": s.get("session"), "participant": s.get("participant"),
                        "verdict": s.get("verdict"), "best_effect": s.get("best_effect"),
                        "best_pair": " + ".join(s.get("best_pair") or []),
                        "nominal_nrmse_pct": h.get("nominal_nrmse_pct"),
                        "augmented_nrmse_pct": h.get("augmented_nrmse_pct"),
                        "shrink_pct": h.get("shrink_pct"),
                        "noise_floor_nrmse_pct": h.get("noise_floor_nrmse_pct")})
        return out

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        verdicts = "; ".join(f"{r['participant'] or r['session']}: {r['verdict']} "
                             f"({r['best_effect']})" for r in self.rows()[:4])
        more = len(self.sessions) - 4
        return short_repr("GapRun", counted(len(self.sessions), "session"),
                          verdicts + (f"; {more} more" if more > 0 else ""),
                          str(self.report) if self.report else "")

    _repr_html_ = html_repr


def run_gap(sessions, out_dir, *, settings: GapSettings | None = None, twin=None,
            sim_session=None, plots: bool = True,
            preprocess: PreprocessSettings | None = None, excluded="qc") -> GapRun:
    """Diagnose each session and write the outputs.

    Parameters
    ----------
    sessions : list of path-like or protocols.session_file.Session
        Session files (each read once, with :data:`nmsid.analysis.gap.data.GAP_DATASETS`), or
        sessions read already (e.g. by a study task that identified them first).
    out_dir : path-like
    settings : GapSettings, optional
    twin, sim_session : path-like, optional
        An external simulation under test (see module).
    plots : bool
        Write the PNG figures.
    preprocess : PreprocessSettings, optional
        Filters, fit rate and input timing (shared with identification).
    excluded : "qc", dict, callable or None
        Trials excluded upstream, never held against the model: by default (``"qc"``)
        the ones the trial quality control (:func:`nmsid.analysis.qc.assess_session`) excludes;
        or a mapping trial name -> reason, or a callable ``path -> mapping`` for several
        sessions (called with the session's file path); None keeps every completed trial.
        They are left out of every fit and score and listed in the report.

    Returns
    -------
    GapRun
    """

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    reports = []
    multi = len(sessions) > 1
    for entry in sessions:
        # read once; QC, pre-processing, the report and the twin all use this session
        session = entry if isinstance(entry, Session) else \
            read_session(entry, datasets=GAP_DATASETS)
        path = session.path
        check_session_data(session, path)  # absurd values: one line, first
        if isinstance(excluded, str) and excluded == "qc":
            excl = assess_session(session).excluded()
        else:
            excl = excluded(path) if callable(excluded) else excluded
        data = load_session(session, preprocess, excluded=excl)
        diag = diagnose(data, settings)
        target = out / Path(path).stem if multi else out
        report = write_outputs(diag, target, session.calibration, plots=plots)
        if twin is not None or sim_session is not None:
            pred = external_predictions(data, twin=twin, sim_session=sim_session,
                                        session=session)
            report["simulation_under_test"] = json_safe(
                _under_test(diag, pred, str(twin or sim_session)))
            (target / "gap_report.json").write_text(json.dumps(report, indent=1) + "\n",
                                                    encoding="utf-8")
        reports.append(report)
    top = out / "gap_report.json"
    if multi:
        votes = Counter(r["best_effect"] for r in reports)
        summary = {"format": "nmsid-gap-report-group", "format_version": 1,
                   "best_effect": votes.most_common(1)[0][0],
                   "votes": dict(votes),
                   "sessions": [{"session": r["session"], "best_effect": r["best_effect"],
                                 "heldout": r["heldout"],
                                 "folder": Path(r["session"]).stem} for r in reports]}
        top.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return GapRun(sessions=reports, report=top)
