"""Outputs of ``nmsid design``: protocol.toml, design.json, report.txt, report.html, a figure.

``protocol.toml`` is a configuration ``nmsid run --config`` and ``nmsid gui`` load (it is
written from the candidate's validated settings and read back through the same loader
before anything else is written).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from nmsid.analysis import plot_style as style
from nmsid.analysis.design.candidates import PAPER_LEVELS, Candidate
from nmsid.analysis.design.predict import DerivedQuantities, SelectionAccuracy
from nmsid.analysis.design.prior import PARAMETERS
from nmsid.analysis.design.search import Evaluation
from nmsid.protocols.config import load_config

#: Caveats printed in every report (the design's model does not see these).
CAVEATS = (
    "The prediction is a Cramer-Rao bound: sensor noise (white, at the prior's level) plus "
    "the assumed per-trial physiological scatter; it is reached only by an efficient "
    "estimator on a correct model (nmsid's fit is within 1.2x of it on simulated data).",
    "Not modelled: fatigue or potentiation over the session (rests keep the paper's duty "
    "cycle, nothing more), dead time or nonlinear recruitment (run nmsid gap on the first "
    "session), curves outside the linear/quadratic/exponential families, and scatter that "
    "differs from the assumed one.",
    "Where the proposal has fewer sE levels than the paper, values between them come from "
    "the curve; a relation that is none of the three families would go unseen.",
    "The prior's families are taken as the truth for the selection accuracy; a first short "
    "session only approximates them.",
    "On physiology that is not second order, a shorter or otherwise different input gives "
    "a different best second-order twin (on MuJoCo musculoskeletal elbows a 4 s chirp "
    "moves wn and zeta by 0.1-0.4 %, an 0.8-8 Hz band by more; bench_design_msk). With a "
    "first session (--scatter-from) whose median fit is below 97 %, the design keeps the "
    "paper's excitation (see 'excitation' above); without one it cannot tell.",
)


def protocol_toml(c: Candidate, header: str = "", joint: str = "elbow") -> str:
    """The ``[protocol]`` table of ``c`` as TOML text; for a joint other than the elbow, its
    top-level ``joint`` first (the session then gets that joint's limits and units)."""
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    if joint != "elbow":
        lines.append(f"joint = {json.dumps(joint)}")
    lines.append("[protocol]")
    for key, value in c.protocol_dict().items():
        if isinstance(value, list):
            text = "[" + ", ".join(f"{v:g}" for v in value) + "]"
        elif isinstance(value, str):
            text = json.dumps(value)
        elif isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, int):
            text = str(value)
        else:
            text = repr(float(value))
        lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def _selection(ev: Evaluation) -> SelectionAccuracy:
    if ev.selection is None:  # design() computes it for the proposal and the paper
        raise ValueError(f"{ev.candidate.label or 'candidate'}: no selection accuracy "
                         "was computed")
    return ev.selection


def _derived_json(derived: list[dict[str, DerivedQuantities]]) -> list[dict]:
    """Per participant ``{parameter: {quantity: (value, se)}}`` (the design.json layout)."""
    return [{name: q.to_dict() for name, q in who.items()} for who in derived]


def write_outputs(out_dir, result, *, prior_source: str, scatter: dict,
                  validation: dict | None, noise_only=None,
                  excitation: dict | None = None, joint: str = "elbow") -> dict:
    """Write every output file; return the ``design.json`` dict.

    Parameters
    ----------
    out_dir : path-like
    result : analysis.design.search.DesignResult
    prior_source : str
    scatter : dict
        The per-trial relative scatter assumed.
    validation : dict or None
        From the simulation runs (``validated_sd_ratio``, realised errors, selection).
    noise_only : (Prediction, Prediction), optional
        Proposal and paper predicted with sensor noise only (drawn dashed in the figure).
    excitation : dict, optional
        ``{"kept_paper_excitation": bool, "why": str}``: whether the search was limited to
        the paper's excitation and why.
    joint : str
        The prior's joint: written into protocol.toml (``joint = "knee"``) and design.json.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prop, paper = result.proposal, result.paper
    c = prop.candidate
    share_pct = 100 * c.stimulation_s / paper.candidate.stimulation_s
    header = (f"nmsid design: {c.describe()}\n"
              f"stimulation {c.stimulation_s:g} s ({share_pct:.0f} % "
              f"of the paper's {paper.candidate.stimulation_s:g} s), prior: {prior_source}")
    toml_path = out / "protocol.toml"
    tmp = out / ".protocol.toml.tmp"
    tmp.write_text(protocol_toml(c, header, joint), encoding="utf-8")
    load_config(tmp)             # the file must load exactly as nmsid run will load it
    os.replace(tmp, toml_path)

    rel_prop = prop.prediction.curve_se / np.abs(prop.prediction.curve_value)
    rel_paper = paper.prediction.curve_se / np.abs(paper.prediction.curve_value)
    per_level = []
    for i, s in enumerate(PAPER_LEVELS):
        row: dict[str, object] = {"sE": s}
        for j, name in enumerate(PARAMETERS):
            row[name] = {"proposal_rel_se": float(np.median(rel_prop[:, i, j])),
                         "paper_rel_se": float(np.median(rel_paper[:, i, j])),
                         "max_ratio": float(np.max(prop.prediction.curve_se[:, i, j]
                                                   / paper.prediction.curve_se[:, i, j]))}
        per_level.append(row)
    doc = {
        "format": "nmsid-design", "format_version": 1,
        "found": bool(result.found),
        "target": result.target.describe(),
        "prior": prior_source,
        **({"joint": joint} if joint != "elbow" else {}),
        "scatter_per_trial_rel": scatter,
        "excitation": excitation or {"kept_paper_excitation": False, "why": ""},
        "protocol": c.protocol_dict(), "protocol_description": c.describe(),
        "stimulation_s": c.stimulation_s,
        "paper_stimulation_s": paper.candidate.stimulation_s,
        "stimulation_fraction": c.stimulation_s / paper.candidate.stimulation_s,
        "session_s": c.session_s, "paper_session_s": paper.candidate.session_s,
        "n_trials": c.n_trials, "paper_n_trials": paper.candidate.n_trials,
        "predicted_sd_ratio": prop.ratio.max,
        "predicted_sd_ratio_per_parameter": prop.ratio.per_parameter,
        "predicted_sd_ratio_median_participant": prop.ratio.median_participant_max,
        "predicted_derived_sd_ratio": prop.derived_ratio,
        "predicted_sd_ratio_definition": (
            "largest ratio, over prior participants, parameters (Kp, wn, zeta) and the "
            "paper's 15 sE levels, of the standard error of the right-family curve fitted "
            "to the proposal's levels to that of the curve fitted to the paper protocol's "
            "levels (both evaluated at the paper's 15 levels, so level sets may differ)"),
        "validated_sd_ratio": None if validation is None else validation["validated_sd_ratio"],
        "validated_sd_ratio_se": None if validation is None else
        validation["validated_sd_ratio_se"],
        "validated_sd_ratio_definition": (
            "largest over parameters of the ratio of realised RMS relative curve errors "
            "(pooled over simulated participants and the paper's 15 levels), proposal / "
            "paper, same participants, each protocol with its own independent draws of "
            "per-trial physiology (the assumed scatter) and sensor noise; "
            "validated_sd_ratio_se is its Monte-Carlo standard error (from the spread "
            "over participants). validation.without_scatter: sensor noise only; "
            "validation.other_scatter: a scatter model the design did not assume"),
        "selection_accuracy": {"proposal": _selection(prop).overall,
                               "paper": _selection(paper).overall,
                               "kind": "predicted (Monte-Carlo on the predicted covariance)"},
        "selection_accuracy_per_parameter": {"proposal": _selection(prop).to_dict(),
                                             "paper": _selection(paper).to_dict()},
        "validation": validation,
        "predicted_per_level": per_level,
        "derived": {"proposal": _derived_json(prop.prediction.derived),
                    "paper": _derived_json(paper.prediction.derived)},
        "search": {"candidates_evaluated": result.n_evaluated, "notes": result.notes},
        "caveats": list(CAVEATS) + ([
            "The proposal is a multisine: nmsid gap's localisation by chirp band and its "
            "chirp-harmonic signatures read time as chirp frequency and do not apply; its "
            "effect ranking and held-out errors do."] if c.input_kind == "multisine" else []),
    }
    if validation is not None:
        doc["validated_selection_accuracy"] = validation["selection_accuracy"]
    with open(out / "design.json", "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1, default=float)
    text = report_text(doc, result)
    (out / "report.txt").write_text(text, encoding="utf-8")
    rel0 = None
    if noise_only is not None:
        rel0 = tuple(q.curve_se / np.abs(q.curve_value) for q in noise_only)
    fig = _figure(out / "design.png", rel_prop, rel_paper, c, paper.candidate, rel0)
    (out / "report.html").write_text(_html(text, fig), encoding="utf-8")
    return doc


def _pm(v: dict) -> str:
    """``ratio +- SE`` of one validation run (the SE needs two participants or more)."""
    se = v.get("validated_sd_ratio_se")
    return f"{v['validated_sd_ratio']:.4f} +- " + (f"{se:.4f}" if se is not None else
                                                  "n/a (one participant)")


def report_text(doc: dict, result) -> str:
    c, paper = result.proposal.candidate, result.paper.candidate
    L = ["nmsid design", "=" * 12, ""]
    if not doc["found"]:
        L.append("NO CANDIDATE MET THE TARGET: the protocol below is the closest one.")
    L += [f"target: {doc['target']}", f"prior: {doc['prior']}",
          "per-trial scatter assumed: " + ", ".join(f"{k} {100 * v:g} %" for k, v in
                                                  doc["scatter_per_trial_rel"].items()),
          "excitation: " + ("the paper's, kept: " if doc["excitation"]["kept_paper_excitation"]
                            else "searched: ") + (doc["excitation"]["why"] or
                                                 "no first session to judge the model by"),
          "",
          f"{'':<22}{'proposal':>26}{'paper':>26}",
          f"{'protocol':<22}{c.label or '-':>26}{'paper':>26}",
          f"{'sE levels':<22}{len(c.sE_levels):>26}{len(paper.sE_levels):>26}",
          f"{'repeats':<22}{c.repeats:>26}{paper.repeats:>26}",
          f"{'trial':<22}{f'{c.steady_s:g} s + {c.chirp_s:g} s {c.input_kind}':>26}"
          f"{f'{paper.steady_s:g} s + {paper.chirp_s:g} s chirp':>26}",
          f"{'band, amplitude':<22}"
          f"{f'{c.chirp_f0_Hz:g}-{c.chirp_f1_Hz:g} Hz, {c.rE_amplitude:g}':>26}"
          f"{f'{paper.chirp_f0_Hz:g}-{paper.chirp_f1_Hz:g} Hz, {paper.rE_amplitude:g}':>26}",
          f"{'rest between trials':<22}{f'{c.rest_s:g} s':>26}{f'{paper.rest_s:g} s':>26}",
          f"{'stimulation':<22}{f'{c.stimulation_s:g} s':>26}{f'{paper.stimulation_s:g} s':>26}",
          f"{'session (no calib.)':<22}{f'{c.session_s / 60:.1f} min':>26}"
          f"{f'{paper.session_s / 60:.1f} min':>26}",
          f"{'selection (predicted)':<22}{doc['selection_accuracy']['proposal']:>26.3f}"
          f"{doc['selection_accuracy']['paper']:>26.3f}"]
    v = doc.get("validation")
    if v:
        L.append(f"{'selection (simulated)':<22}{v['selection_accuracy']['proposal']:>26.3f}"
                 f"{v['selection_accuracy']['paper']:>26.3f}")
    median_ratio = doc["predicted_sd_ratio_median_participant"]
    L += ["", f"predicted_sd_ratio {doc['predicted_sd_ratio']:.4f} (curves, worst participant, "
              f"parameter and level; median participant {median_ratio:.4f}); "
              f"derived quantities {doc['predicted_derived_sd_ratio']:.4f}"]
    if v:
        L.append(f"validated_sd_ratio {_pm(v)} (Monte-Carlo SE) over "
                 f"{v['n_participants']} simulated participants ({v['population']}), "
                 "under the assumed scatter, each protocol with its own draws")
        for name in PARAMETERS:
            L.append(f"  realised RMS curve error {name:<9} proposal "
                     f"{100 * v['curve_rms_rel']['proposal'][name]:.3f} %  paper "
                     f"{100 * v['curve_rms_rel']['paper'][name]:.3f} %")
        w = v.get("without_scatter")
        if w:
            L.append(f"without physiological scatter (sensor noise and model bias only): "
                     f"validated_sd_ratio {_pm(w)}, selection "
                     f"{w['selection_accuracy']['proposal']:.3f} vs paper "
                     f"{w['selection_accuracy']['paper']:.3f}")
            for name in PARAMETERS:
                L.append(f"  realised RMS curve error {name:<9} proposal "
                         f"{100 * w['curve_rms_rel']['proposal'][name]:.4f} %  paper "
                         f"{100 * w['curve_rms_rel']['paper'][name]:.4f} %")
            if w["validated_sd_ratio"] > 1 + 0.02:
                L.append("  -> where sensor noise alone limits a parameter, the shorter "
                         "protocol's error is larger (the bound's seconds-for-variance "
                         "trade); the design relies on trial-to-trial scatter dominating, "
                         "as it does in the paper's data. Check that on your first session.")
        o = v.get("other_scatter")
        if o:
            L.append(f"under a scatter model the design did not assume ({o['model']}, same "
                     f"SDs): validated_sd_ratio {_pm(o)}, selection "
                     f"{o['selection_accuracy']['proposal']:.3f} vs paper "
                     f"{o['selection_accuracy']['paper']:.3f}")
    L += ["", "predicted relative SE of the curves at the paper's levels, % (median over the "
              "prior's participants), proposal / paper:",
          f"{'sE':>6}" + "".join(f"{n:>22}" for n in PARAMETERS)]
    for row in doc["predicted_per_level"]:
        L.append(f"{row['sE']:>6.2f}" + "".join(
            f"{100 * row[n]['proposal_rel_se']:>11.3g}{100 * row[n]['paper_rel_se']:>11.3g}"
            for n in PARAMETERS))
    L += ["", "what this does not promise:"] + [f"- {x}" for x in doc["caveats"]]
    return "\n".join(L) + "\n"


def _figure(path: Path, rel_prop, rel_paper, c, paper, rel0=None) -> str | None:
    """Predicted SE of each parameter's curve at the paper's levels, proposal against the
    paper's protocol (PNG and PDF); None without matplotlib."""
    try:
        plt = style.pyplot()
    except ImportError:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
    x = np.asarray(PAPER_LEVELS)
    for j, (ax, name) in enumerate(zip(axes, PARAMETERS, strict=True)):
        ax.plot(x, 100 * np.median(rel_paper[:, :, j], axis=0), "-", color="0.5", lw=4,
                alpha=0.6, label=f"paper's protocol ({paper.stimulation_s:g} s)")
        ax.plot(x, 100 * np.median(rel_prop[:, :, j], axis=0), "s-", color="C0", ms=4,
                label=f"proposal ({c.stimulation_s:g} s)")
        if rel0 is not None:
            ax.plot(x, 100 * np.median(rel0[1][:, :, j], axis=0), "--", color="0.5",
                    label="paper's, sensor noise only")
            ax.plot(x, 100 * np.median(rel0[0][:, :, j], axis=0), "--", color="C0",
                    label="proposal, sensor noise only")
            ax.set_yscale("log")
        for i, s in enumerate(c.sE_levels):
            ax.axvline(s, color="C0", alpha=0.15,
                       label="proposal's levels" if i == 0 else None)
        ax.set_title(style.SYMBOLS.get(name, name).split(" (")[0])
        ax.set_xlabel(r"stimulation level $s_E$")
        ax.set_ylabel("predicted relative SE of the curve (%)")
    style.legend_outside(axes[-1], "right")
    fig.suptitle("predicted standard error of each curve at the paper's levels (median over "
                 "the prior's participants)")
    fig.tight_layout()
    style.save(fig, path)
    return path.name


def _html(text: str, fig: str | None) -> str:
    img = f'<img src="{fig}" alt="predicted SE per level">' if fig else ""
    return ("<!doctype html><meta charset='utf-8'><title>nmsid design</title>"
            f"<h1>nmsid design</h1>{img}<pre>{html.escape(text)}</pre>\n")
