"""Tables and files of an identification run: ``parameters.csv``, ``model_selection.json``,
paper-like text tables and the problems list.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from nmsid.analysis.model_selection import AVERAGE_LABEL, SelectionResult
from nmsid.analysis.settings import PARAMETER_NAMES
from nmsid.protocols.printable import escape_controls

PARAMETER_COLUMNS = ("participant", "sE", "Kp", "wn_rad_s", "zeta", "fit_pct", "n_trials",
                     "Kp_se", "wn_se", "zeta_se", "converged", "resid_whiteness_pass",
                     "resid_independence_pass", "baseline_N", "n_repeats_used",
                     "n_repeats_excluded", "qc_flag")
MODEL_TITLES = {"linear": "Linear", "quadratic": "Quadratic", "exponential": "Exponential"}
PARAMETER_TITLES = {"Kp": "Kp (N)", "wn_rad_s": "wn (rad/s)", "zeta": "zeta"}
"""Titles of an elbow force session; :func:`parameter_titles` gives a joint's."""


def parameter_titles(unit: str = "N") -> dict[str, str]:
    """Each parameter's title with the session joint's unit (``Kp (N m)`` for a torque
    joint, ``docs/joints.md``): the one place reports and figures take it from."""
    return {**PARAMETER_TITLES, "Kp": f"Kp ({unit})"}


def measured_title(session_result) -> str:
    """What a session measured, for titles: ``force (N)``, ``knee torque (N m)`` (the
    elbow's stays ``force (N)`` as before joints)."""
    quantity = getattr(session_result, "quantity", "force")
    unit = getattr(session_result, "unit", "N")
    joint = getattr(session_result, "joint", "elbow")
    return f"{quantity} ({unit})" if joint == "elbow" else f"{joint} {quantity} ({unit})"


def _fmt(value, digits: int = 6) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.{digits}g}"
    return str(value)


def write_parameters_csv(session_results, path: str | Path) -> Path:
    """One row per participant and sE (columns ``PARAMETER_COLUMNS``; empty = not
    identified; flags are 1/0)."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(PARAMETER_COLUMNS)
        for res in session_results:
            for row in res.rows():
                w.writerow([escape_controls(_fmt(row[c], 8 if c in ("Kp", "wn_rad_s",
                                                                       "zeta") else 6))
                            for c in PARAMETER_COLUMNS])
    return path


def _json_safe(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def write_model_selection_json(selection: SelectionResult, path: str | Path,
                               extra: dict | None = None) -> Path:
    """The whole selection (every comparison, point, fit, AICc, trend, sum) as JSON."""
    data = selection.to_dict()
    if extra:
        data.update(extra)
    Path(path).write_text(json.dumps(_json_safe(data), indent=2) + "\n", encoding="utf-8")
    return Path(path)


def parameter_table(session_result) -> str:
    """The identified parameters of one session as aligned text."""
    kp_title = parameter_titles(getattr(session_result, "unit", "N"))["Kp"]
    head = (f"{'sE':>5} {kp_title:>9} {'+-':>7} {'wn (rad/s)':>10} {'+-':>7} {'zeta':>7} "
            f"{'+-':>7} {'fit %':>6} {'n':>2}  flags")
    measured = measured_title(session_result)
    lines = [f"participant {session_result.participant}  ({session_result.source})"
             + ("" if measured == "force (N)" else f"  {measured}"), head]
    for lv in session_result.levels:
        f = lv.fit
        if f is None:
            lines.append(f"{lv.sE:5.2f}  not identified")
            continue
        flags = []
        if not f.converged:
            flags.append("not converged")
        if not f.residual_tests.independence_pass:
            flags.append("resid-input corr")
        lines.append(f"{lv.sE:5.2f} {f.Kp:9.4f} {f.Kp_se:7.4f} {f.wn_rad_s:10.3f} "
                     f"{f.wn_se:7.3f} {f.zeta:7.4f} {f.zeta_se:7.4f} {f.fit_pct:6.2f} "
                     f"{lv.n_trials:2d}  {', '.join(flags)}")
    sc = getattr(session_result, "scatter", None)
    if sc is not None:
        lines += ["", ("trial-to-trial scatter (each repeat fitted on its own; SD of the "
                       "log-parameter between repeats, %)"), sc.table()]
    fat = getattr(session_result, "fatigue", None)
    if fat is not None:
        lines.append(fat.sentence())
    return "\n".join(lines)


SCATTER_COLUMNS = ("participant", "sE", "n_trials", "parameter", "cv_pct", "ci_low_pct",
                   "ci_high_pct", "estimation_cv_pct", "physiological_cv_pct", "dof")


def write_scatter_csv(session_results, path: str | Path) -> Path:
    """Trial-to-trial scatter per participant, sE (``all``: pooled) and parameter
    (columns ``SCATTER_COLUMNS``; see :mod:`nmsid.analysis.scatter`)."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(SCATTER_COLUMNS)
        for res in session_results:
            sc = getattr(res, "scatter", None)
            if sc is None:
                continue
            rows = [(f"{lv.sE:g}", lv.n_trials, getattr(lv, p)) for lv in sc.levels
                    for p in PARAMETER_NAMES]
            rows += [("all", sc.pooled(p).n_trials, sc.pooled(p)) for p in PARAMETER_NAMES]
            for sE, n, ps in rows:
                w.writerow([escape_controls(str(res.participant)), sE, n, ps.parameter]
                           + [_fmt(float(getattr(ps, c)), 4) for c in SCATTER_COLUMNS[4:9]]
                           + [ps.dof])
    return path


def selection_tables(selection: SelectionResult, unit: str = "N") -> str:
    """The paper's Tables 1-9 for this run: per parameter, AICc per participant x model,
    the selected model with its trend, and the AICc sums (Kp in ``unit``, the joint's)."""
    models = selection.settings.models
    labels = [AVERAGE_LABEL] + selection.participants
    titles = parameter_titles(unit)
    out = []
    for name in PARAMETER_NAMES:
        title = titles[name]
        out.append(f"== {title}: AICc per participant and model ==")
        out.append(f"{'participant':<14}" + "".join(f"{MODEL_TITLES[m]:>13}" for m in models))
        for label in labels:
            c = selection.comparison(name, label)
            if c is None:
                continue
            cells = []
            for m in models:
                f = c.fits.get(m)
                cells.append(f"{f.aicc:13.4g}" if f is not None and f.selectable
                             else f"{'n/a':>13}")
            out.append(f"{label:<14}" + "".join(cells))
        out.append("")
        out.append(f"== {title}: selected model and trend ==")
        for label in labels:
            c = selection.comparison(name, label)
            if c is None:
                continue
            removed = sum(1 for p in c.points if not p.used and p.note.startswith("IQR"))
            extra = f"  [{removed} IQR outlier(s) removed]" if removed else ""
            if c.selected is None:
                out.append(f"{label:<14}no model selectable{extra}")
            else:
                trend = c.trend.text if c.trend is not None else ""
                out.append(f"{label:<14}{MODEL_TITLES[c.selected]:<12} {trend}{extra}")
        out.append("")
        out.append(f"== {title}: sum of AICc across participants ==")
        for m in models:
            n = selection.aicc_sum_counts[name][m]
            total = selection.aicc_sums[name][m]
            note = "" if n == len(selection.participants) else \
                f"  (over {n} of {len(selection.participants)} participants)"
            out.append(f"{MODEL_TITLES[m]:<14}{total:13.4g}{note}")
        out.append("")
    return "\n".join(out)


def write_text(text: str, path: str | Path) -> Path:
    # names and reasons come from session files: no raw control character in the file
    Path(path).write_text(escape_controls(text.rstrip("\n")) + "\n", encoding="utf-8")
    return Path(path)
