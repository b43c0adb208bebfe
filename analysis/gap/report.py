"""Outputs of ``nmsid gap``: ``gap_report.json``, ``report.html`` with its figures, and the
augmented ``twin.json``."""

from __future__ import annotations

import html
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.analysis.gap import plots
from nmsid.analysis.gap.diagnose import Diagnosis, ranking
from nmsid.analysis.gap.evidence import confusable_pairs, explain, signatures
from nmsid.analysis.gap.fit import Problem
from nmsid.analysis.gap.localize import Localization, localization
from nmsid.analysis.gap.models import (
    FORMS,
    FinalContext,
    canonical_asymmetry,  # noqa: F401 (re-exported)
    fatigue_loss_pct,
    nuisance_basis,
)
from nmsid.analysis.gap.twin_out import effect_entries, twin_dict, write_twin
from nmsid.analysis.muscle.report import muscle_section, plot_muscle, twin_item
from nmsid.analysis.parameters import Parameters
from nmsid.analysis.twin import source_entry
from nmsid.protocols.effects import EFFECT_NAMES
from nmsid.protocols.printable import escape_controls

log = logging.getLogger(__name__)


@dataclass
class GapReport:
    """What :func:`build_report` makes of one diagnosis.

    Attributes
    ----------
    report : dict
        The ``gap_report.json`` document (JSON-safe; its fields: docs/gap.md).
    localization : Localization
        Where the gap sits (:func:`nmsid.analysis.gap.localize.localization`), with the
        winner's footprint on the transfer function; what the figures draw.
    twin : dict or None
        The augmented ``twin.json`` document (None without a calibration).
    """

    report: dict
    localization: Localization
    twin: dict | None


def _drift_amplitude(diag: Diagnosis) -> tuple[float, float]:
    """RMS of the fitted non-linear baseline in the window, and the same corrected for the
    part of a flat-spectrum wander below ``corner_Hz`` that offset and trend absorb."""
    fit = diag.full_fit
    d = diag.data
    prob = Problem(d, fit.candidate, fit.corner_Hz)
    lev = prob.levels
    x = prob.unit_response(fit.wn_rad_s[lev], fit.zeta[lev], fit.p_shared)
    raw = d.y_N - fit.Kp[d.level][:, None] * x
    Qd = nuisance_basis(d.t_eval_s, fit.corner_Hz)
    Q0 = nuisance_basis(d.t_eval_s, 0.0)
    base = (raw @ Qd) @ Qd.T - (raw @ Q0) @ Q0.T
    rms = float(np.sqrt(np.mean(base ** 2)))
    t = d.t_eval_s
    shares = []
    for f in np.linspace(fit.corner_Hz / 50, fit.corner_Hz, 50):
        for s in (np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)):
            shares.append(float(np.sum((s - Q0 @ (Q0.T @ s)) ** 2) / np.sum(s ** 2)))
    frac = max(float(np.mean(shares)), 1e-3)
    return rms, rms / math.sqrt(frac)


@dataclass(frozen=True)
class FinalParams:
    """The final (all-trial) fit's effect parameters (:func:`final_params`).

    Attributes
    ----------
    values : dict of str to float
        Our parameters by name (e.g. ``L_s``, ``tau_s``, ``rate_per_s``, ``wn_ratio``,
        ``corner_Hz``), ``input_timing_s`` (the session's estimate plus the model's
        correction), and the derived figures of each effect (loss %, nonlinearity index,
        canonical asymmetry, drift amplitude): ``gap_report.json``'s ``best_params``.
    curve : callable or None
        The fitted recruitment curve ``h(I)`` when the model has a recruitment effect
        (what the twin's recruitment entry is projected from), else None.
    """

    values: dict[str, Any]
    curve: Any = None

    def to_dict(self) -> dict:
        """The report's form (``best_params``): :attr:`values`."""
        return dict(self.values)

    def for_twin(self) -> dict:
        """:attr:`values` with the curve under ``_curve``, as the effect forms'
        ``twin_params`` read them (``analysis.gap.models``)."""
        out = dict(self.values)
        if self.curve is not None:
            out["_curve"] = self.curve
        return out


def final_params(diag: Diagnosis) -> FinalParams:
    """The final (all-trial) fit's effect parameters, in our terms plus derived figures
    (loss %, nonlinearity index, canonical asymmetry, drift amplitude).

    Parameters
    ----------
    diag : Diagnosis

    Returns
    -------
    FinalParams
    """
    fit = diag.full_fit
    p = dict(fit.params)
    effs = fit.candidate.effects
    session_s = diag.data.timing.delay_s if diag.data.timing else 0.0
    p["input_timing_s"] = session_s + p.pop("timing_correction_s", 0.0)
    for e in effs:
        FORMS[e].final(p, FinalContext(q=fit.candidate.sub(fit.p_shared, e),
                                       sE_levels=diag.data.sE_levels,
                                       drift_amplitude=lambda: _drift_amplitude(diag)))
    curve = p.pop("_curve", None)
    return FinalParams(values=p, curve=curve)


def _level_params(diag: Diagnosis):
    fit = diag.full_fit
    Kp, wn, zeta = fit.Kp.copy(), fit.wn_rad_s.copy(), fit.zeta.copy()
    if "wn_ratio" in fit.params:  # a flexor/extensor asymmetry
        wr = fit.params["wn_ratio"]
        if wr < 1.0:  # flip to the reported orientation: the other muscle is "extensor"
            wn = wn * wr
            zeta = zeta * fit.params["zeta_ratio"]
    return Kp, wn, zeta


def _excess_shrink(diag: Diagnosis, nom_pct: float, aug_pct: float) -> float:
    e0 = diag.excess_pct(nom_pct)
    return 100.0 * (1 - diag.excess_pct(aug_pct) / e0) if e0 > 0 else float("nan")


def _row(r) -> dict:
    params = dict(r.params)
    if "rate_per_s" in params:
        params["gain_loss_pct"] = fatigue_loss_pct(params["rate_per_s"])
    return {"effect": r.label, "params": params,
            "heldout_nrmse_pct": r.heldout_nrmse_pct,
            "insample_nrmse_pct": r.insample_nrmse_pct,
            "delta_ic": r.delta_ic, "delta_k": r.delta_k, "n_eff_fraction": r.nu,
            "shrink_pct": r.shrink_pct, "supported": r.supported, "fit_s": r.fit_s}


def json_safe(obj):
    """JSON-safe (NaN -> None, numpy -> Python)."""
    if isinstance(obj, (dict, Parameters)):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    return obj


def _fatigue_entry(assessment) -> dict | None:
    """The verdict's fatigue estimate as plain JSON (None when there is none)."""
    fatigue = getattr(assessment, "fatigue", None)
    return None if fatigue is None else fatigue.as_dict()


def fatigue_for_twin(diag: Diagnosis, effects: list[dict]) -> dict:
    """The session's fatigue (the verdict's, from each trial's gain) as a twin-file effect
    when it is significant and the final model does not carry fatigue already.

    The twin file's fatigue (and the FMU's) has two shapes, ``linear`` and
    ``exponential``: a linear loss is written as such, an exponential or saturating one as
    ``exponential`` with the same loss over the session's stimulation
    (``reference_stim_s``), which ``nmsid twin simulate`` and the FMU reproduce at the
    session's end (a saturating loss is reached earlier in the session than the file's
    shape says: ``note``). The level gains of the nominal fit are the session's average
    gains: they are divided by the mean fitted gain over the trials, so that the twin
    starts unfatigued. Potentiation (a gain that grows) has no twin effect (``note``).

    Returns
    -------
    dict
        ``entry`` (the effect, or None), ``kp_scale`` and ``note``.
    """
    fat = getattr(diag.assessment, "fatigue", None)
    if fat is None or not fat.significant or not fat.estimated:
        return {"entry": None, "kp_scale": 1.0, "note": "no significant fatigue"}
    if any(e["name"] == "fatigue" for e in effects):
        return {"entry": None, "kp_scale": 1.0,
                "note": "fatigue is part of the final model (the candidate's fit)"}
    if fat.loss_pct <= 0:
        return {"entry": None, "kp_scale": 1.0,
                "note": "potentiation: the twin file has no effect for a growing gain"}
    shape = "linear" if fat.shape == "linear" else "exponential"
    d = diag.data
    c = d.cum_stim_s + 0.5 * d.chirp_s
    mean_gain = float(np.mean(fat.gain_at(c)))
    entry = {"name": "fatigue", "params": {"shape": shape,
                                           "gain_loss_pct": min(float(fat.loss_pct), 99.0),
                                           "reference_stim_s": float(fat.total_stim_s)}}
    note = (f"the session's {fat.shape} fatigue: {fat.loss_pct:.1f} % lost over "
            f"{fat.total_stim_s:.0f} s of stimulation")
    if fat.shape == "saturating":
        note += (" (written as exponential with the same loss at the session's end: the "
                 "twin file and the FMU have no saturating shape yet)")
    return {"entry": entry, "kp_scale": 1.0 / mean_gain if mean_gain > 0 else 1.0,
            "note": note}


def build_report(diag: Diagnosis, calibration=None) -> GapReport:
    """The report, the localization and (with a calibration) the augmented twin of one
    diagnosis.

    Parameters
    ----------
    diag : Diagnosis
    calibration : protocols.session_file.Calibration, optional
        The session's calibration; without it no twin is made.

    Returns
    -------
    GapReport
    """
    loc = localization(diag)
    sig = signatures(diag, loc)
    if sig.effect_footprint is not None:
        fp_ = sig.effect_footprint
        loc.frequency["footprint"] = {"f_Hz": list(fp_.f_Hz),
                                      "gain_error_dB": list(fp_.gain_error_dB),
                                      "phase_error_deg": list(fp_.phase_error_deg)}
    final = diag.best_pair or diag.best
    fparams = final_params(diag)
    fp = fparams.to_dict()
    nom = diag.nominal
    aug_pct = final.heldout_nrmse_pct if final else nom.heldout_nrmse_pct
    twin = None
    fatigue_twin = None
    if calibration is not None:
        Kp, wn, zeta = _level_params(diag)
        effects = effect_entries(fparams.for_twin(), diag.full_fit.candidate.effects,
                                 diag.data.sE_levels) if final else []
        fatigue_twin = fatigue_for_twin(diag, effects)
        if fatigue_twin.get("entry") is not None:
            effects = sorted(effects + [fatigue_twin["entry"]],
                             key=lambda e: EFFECT_NAMES.index(e["name"]))
            Kp = Kp * fatigue_twin["kp_scale"]
        twin = twin_dict(participant=diag.data.participant or "unknown",
                         source=[source_entry(diag.data.path)], calibration=calibration,
                         sE_levels=diag.data.sE_levels, Kp=Kp, wn_rad_s=wn, zeta=zeta,
                         effects=effects, measured=diag.data.measured)
    in_aug = final.insample_nrmse_pct if final else nom.insample_nrmse_pct
    a = diag.assessment
    loc_dict = loc.to_dict()
    report: dict[str, Any] = {
        "format": "nmsid-gap-report", "format_version": 1,
        "session": diag.data.path, "participant": diag.data.participant,
        # optional (docs/joints.md): every _N figure below is in this unit
        "joint": diag.data.measured[0], "measured_unit": diag.data.measured[2],
        "verdict": a.get("verdict"), "verdict_sentence": a.get("sentence"),
        "remaining": a.get("remaining"), "nominal_gap": a.get("nominal_gap"),
        "not_named": a.get("not_named"),
        "likely": a.get("likely"),
        "qc": a.get("qc"),
        "candidates_not_fitted": diag.candidates_skipped,
        "fatigue": _fatigue_entry(a),
        "fatigue_in_twin": fatigue_twin,
        "n_trials": diag.data.n_trials, "skipped_trials": diag.data.skipped,
        "excluded_trials": [{"trial": k, "reason": v} for k, v in diag.data.excluded.items()],
        "input_timing": diag.data.timing.as_dict() if diag.data.timing else None,
        "folds": [{"held_out_repeat": f.held_out_repeat, "n_train": len(f.train),
                   "n_test": len(f.test)} for f in diag.folds],
        "best_effect": diag.best_effect.value,
        "best_pair": [e.value for e in diag.best_pair.candidate.effects]
        if diag.best_pair else None,
        "best_params": fp,
        "ranking": [_row(r) for r in ranking(diag)],
        "heldout": {"nominal_nrmse_pct": nom.heldout_nrmse_pct,
                    "augmented_nrmse_pct": aug_pct,
                    "shrink_pct": 100.0 * (1 - aug_pct / nom.heldout_nrmse_pct),
                    "nominal_fit_pct": 100 - nom.heldout_nrmse_pct,
                    "augmented_fit_pct": 100 - aug_pct,
                    "noise_floor_nrmse_pct": diag.noise_floor_nrmse_pct,
                    "sensor_floor_nrmse_pct": diag.sensor_floor_nrmse_pct,
                    "nominal_excess_pct": diag.excess_pct(nom.heldout_nrmse_pct),
                    "augmented_excess_pct": diag.excess_pct(aug_pct),
                    "excess_shrink_pct": _excess_shrink(diag, nom.heldout_nrmse_pct, aug_pct)},
        "insample": {"nominal_nrmse_pct": nom.insample_nrmse_pct,
                     "augmented_nrmse_pct": in_aug},
        "localization": {k: v for k, v in loc_dict.items()
                         if k not in ("frequency", "spectrum")},
        "frequency": loc_dict["frequency"],
        "low_frequency": {k: {kk: vv for kk, vv in v.items() if kk not in ("f_Hz", "power")}
                          for k, v in loc_dict["spectrum"].items()},
        "evidence": {"summary": explain(diag, sig), "signatures": sig.to_dict(),
                     "confusable_pairs": confusable_pairs(diag, sig)},
        "settings": {k: (list(v) if isinstance(v, tuple) else v)
                     for k, v in vars(diag.settings).items() if k != "candidates"},
        "elapsed_s": diag.elapsed_s,
    }
    report["settings"]["candidates"] = [e.value for e in diag.settings.candidates]
    report["muscle_twin"] = muscle_section(diag)
    if twin is not None and diag.muscle is not None:
        twin["muscle_model"] = twin_item(diag)
    return GapReport(json_safe(report), loc, twin)


def write_outputs(diag: Diagnosis, out_dir, calibration=None, *, plots: bool = True) -> dict:
    """Write ``gap_report.json``, ``twin.json`` (if a calibration is known), the figures and
    ``report.html`` into ``out_dir``; returns the report dict."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    built = build_report(diag, calibration)
    report, loc, twin = built.report, built.localization, built.twin
    if twin is not None:
        write_twin(out / "twin.json", twin)
        report["twin_file"] = "twin.json"
    figures = []
    if plots:
        figures = _figures(diag, report, loc, out)
    report["figures"] = figures
    (out / "gap_report.json").write_text(json.dumps(report, indent=1) + "\n",
                                         encoding="utf-8")
    # names and reasons come from the session file: no control character reaches the page
    (out / "report.html").write_text(escape_controls(_html(report, figures)),
                                     encoding="utf-8")
    return report


#: Keys of figures the plots draw as numbers (None in the JSON when not computed).
_NUMERIC_KEYS = ("_pct", "_N", "_N2", "_dB", "_deg", "ratio_to_noise", "to_noise_floor")


def _nan_for_none(obj, key: str = ""):
    """The report's form with its numeric figures that could not be computed (None) back
    as NaN: what the figures draw (matplotlib leaves a NaN bar or point out; None would
    fail). Other None values (no pair, no note) stay None."""
    if isinstance(obj, dict):
        return {k: _nan_for_none(v, k) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nan_for_none(v, key) for v in obj]
    if obj is None and key.endswith(_NUMERIC_KEYS):
        return float("nan")
    return obj


def _figures(diag: Diagnosis, report: dict, localized: Localization, out: Path) -> list[str]:
    """Draw every figure; one that fails is listed in ``report["figures_failed"]`` with
    its reason (and logged) and the report is written all the same."""
    loc = localized.to_dict()    # the figures draw the report's form
    names: list[str] = []
    failed: list[dict] = []

    def draw(name: str, fn) -> None:
        try:
            fn(out / name)
        except Exception as exc:   # noqa: BLE001 - a figure never costs the report
            log.warning("figure %s not drawn: %s: %s", name, type(exc).__name__, exc)
            failed.append({"figure": name, "reason": f"{type(exc).__name__}: {exc}"})
        else:
            names.append(name)

    floor = diag.noise_floor_nrmse_pct
    draw("where.png", lambda p: plots.plot_where(loc, p, floor))
    draw("frequency.png", lambda p: plots.plot_frequency(loc, p))
    draw("drift_fatigue.png",
         lambda p: plots.plot_spectrum_and_gain(loc, p, diag.data.chirp_f0_Hz))
    if report.get("remaining") and report["remaining"]["where"].get("sE"):
        rep = _nan_for_none(report)
        draw("remaining.png", lambda p: plots.plot_remaining(rep, p))
    m = report.get("muscle_twin")
    if m and m.get("converged", True):    # a fit that did not converge has nothing to draw
        ms = _nan_for_none(m)
        draw("muscle.png", lambda p: plot_muscle(ms, p))
    if report["ranking"]:         # none when no candidate was needed (candidates_not_fitted)
        rk = _nan_for_none(report["ranking"])
        muscle = _nan_for_none(m) if m else None
        winner = plots.winner_label(report)
        draw("ranking.png", lambda p: plots.plot_ranking(rk, diag.nominal.heldout_nrmse_pct,
                                                         floor, p, muscle=muscle,
                                                         winner=winner))
    ok = np.flatnonzero(diag.tested)
    if len(ok):
        r_nom = diag.nominal.heldout_resid[ok]
        i = ok[int(np.argmax(np.nan_to_num(np.sum(r_nom ** 2, axis=1), nan=-1.0)))]
        final = diag.best_pair or diag.best
        ref = diag.reference[i]
        title = (f"held-out trial {diag.data.trials[i].name} (sE "
                 f"{diag.data.trials[i].sE:g}): worst nominal fit")
        draw("example.png", lambda p: plots.plot_example(
            diag.data.t_eval_s, ref, ref - diag.nominal.heldout_resid[i],
            ref - final.heldout_resid[i] if final else None, title, p,
            quantity=diag.data.measured[1], unit=diag.data.measured[2]))
    if failed:
        report["figures_failed"] = failed
    return names


def _table(rows: list[dict], cols: list[tuple[str, str, str]]) -> str:
    head = "".join(f"<th>{html.escape(c[1])}</th>" for c in cols)
    body = []
    for r in rows:
        cells = []
        for key, _, fmt in cols:
            v = r.get(key)
            cells.append(f"<td>{html.escape(fmt.format(v) if v is not None and fmt else str(v))}"
                         "</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def _fmt(v, spec: str = ".3g") -> str:
    return "n/a" if v is None else format(v, spec)


def _html(report: dict, figures: list[str]) -> str:
    h = report["heldout"]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>nmsid gap report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;"
        "font-size:90%}</style></head><body>",
        f"<h1>Sim-to-real gap: {html.escape(str(report['participant']))}</h1>",
        f"<p>Session <code>{html.escape(str(report['session']))}</code>, "
        f"{report['n_trials']} trials, {len(report['folds'])}-fold cross-validation by "
        "repeat (held-out figures never come from trials used in fitting).</p>",
        f"<h2>Verdict: <code>{html.escape(str(report['verdict']))}</code>"
        + (f" (<code>{html.escape(report['best_effect'])}</code>)"
           if report["best_effect"] != "none" and not report.get("best_pair") else "")
        + (f" (pair: {html.escape(' + '.join(report['best_pair']))})"
           if report.get("best_pair") else "") + "</h2>",
        f"<p><b>{html.escape(str(report.get('verdict_sentence') or ''))}</b></p>",
    ]
    if report.get("excluded_trials"):
        parts.append("<p>Trials excluded upstream and not held against the model: "
                     + html.escape("; ".join(f"{e['trial']} ({e['reason']})"
                                             for e in report["excluded_trials"])) + "</p>")
    if report.get("not_named"):
        parts.append(f"<p>{html.escape(report['not_named'])}.</p>")
    parts.append("<ul>")
    parts += [f"<li>{html.escape(line)}</li>" for line in report["evidence"]["summary"]]
    parts.append("</ul>")
    parts.append(
        f"<p>Held-out NRMSE: nominal {_fmt(h['nominal_nrmse_pct'])} %, augmented "
        f"{_fmt(h['augmented_nrmse_pct'])} % (shrink {_fmt(h['shrink_pct'], '.0f')} %); "
        f"repeat-to-repeat noise floor {_fmt(h['noise_floor_nrmse_pct'])} %, sensor noise in "
        "the steady lead-in "
        f"{_fmt(h['sensor_floor_nrmse_pct'])} %; the gap beyond sensor noise shrinks "
        f"{_fmt(h['excess_shrink_pct'], '.0f')} %. In-sample: nominal "
        f"{_fmt(report['insample']['nominal_nrmse_pct'])} %, augmented "
        f"{_fmt(report['insample']['augmented_nrmse_pct'])} %.</p>")
    parts.append("<h2>Which: ranking</h2>")
    if report.get("candidates_not_fitted"):
        parts.append(f"<p>{html.escape(report['candidates_not_fitted'])} "
                     "(<code>--all-candidates</code> fits and ranks them).</p>")
    rows = [dict(r, params=json.dumps({k: (round(v, 5) if isinstance(v, float) else v)
                                       for k, v in r["params"].items()}))
            for r in report["ranking"]]
    parts.append(_table(rows, [("effect", "candidate", ""), ("params", "fitted params", ""),
                               ("heldout_nrmse_pct", "held-out NRMSE %", "{:.3f}"),
                               ("shrink_pct", "shrink %", "{:.1f}"),
                               ("delta_ic", "dIC (N_eff)", "{:.1f}"),
                               ("n_eff_fraction", "N_eff/N", "{:.3f}"),
                               ("supported", "supported", "")]))
    for name in figures:
        parts.append(f"<h3>{html.escape(name)}</h3><img src='{html.escape(name)}' "
                     "style='max-width:100%'>")
    parts.append("<h2>Where: held-out NRMSE by location</h2>")
    loc = report["localization"]
    unit = str(report.get("measured_unit") or "N")
    u2 = f"{unit}^2" if unit == "N" else f"({unit})^2"
    for key, label, cols in (
            ("sE", "by sE", [("sE", "sE", "{:.2f}"), ("nrmse_pct", "NRMSE %", "{:.3f}"),
                             ("residual_power_N2", f"residual power {u2}", "{:.3g}")]),
            ("band", "by chirp band", [("f_lo_Hz", "from Hz", "{:g}"),
                                       ("f_hi_Hz", "to Hz", "{:g}"),
                                       ("nrmse_pct", "NRMSE %", "{:.3f}"),
                                       ("residual_power_N2", f"residual power {u2}",
                                        "{:.3g}")]),
            ("deviation", "by rE - 0.5", [("d_lo", "from", "{:+.2f}"), ("d_hi", "to", "{:+.2f}"),
                                          ("nrmse_pct", "NRMSE %", "{:.3f}"),
                                          ("residual_mean_N", f"mean residual {unit}",
                                           "{:+.4f}")])):
        parts.append(f"<h3>{label}</h3><table><tr><td>nominal"
                     f"{_table(loc['nominal'][key], cols)}</td>")
        if "augmented" in loc:
            parts.append(f"<td>augmented{_table(loc['augmented'][key], cols)}</td>")
        parts.append("</tr></table>")
    parts.append("<h2>Confusable pairs</h2><pre>"
                 + html.escape(json.dumps(report["evidence"]["confusable_pairs"], indent=1))
                 + "</pre>")
    if report.get("twin_file"):
        parts.append("<p>The augmented model is in <code>twin.json</code>; run it with "
                     "<code>sim_backends.participant_from_twin</code> (or <code>nmsid run "
                     "--backend sim</code> with that participant).</p>")
    parts.append("</body></html>")
    return "\n".join(parts)
