"""The GUI's two calls into ``analysis``: per-level identification and model selection.

Both run in worker threads of the panels. They adapt the analysis package's result
objects to what the panels draw, so the panels do not depend on its classes.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from nmsid.analysis.identify import identify_level as _identify
from nmsid.analysis.qc import assess_level
from nmsid.analysis.run import run_identification
from nmsid.rig.gui.results_panel import ModelFit, ParameterSelection, SelectionView


def identify_level(trials):
    """Identify one sE level from its trials (``analysis.identify.identify_level``).

    Returns the fitted second-order model (attributes ``Kp``, ``wn_rad_s``, ``zeta``,
    ``fit_pct``).

    Raises
    ------
    ValueError
        If nothing could be estimated; the message lists the analysis' reasons.
    """
    result = _identify(list(trials))
    if result.fit is None:
        raise ValueError("; ".join(result.problems) or "no parameters estimated")
    return result.fit


def trial_verdicts(trials_by_index: dict) -> dict[int, tuple[str, str]]:
    """The quality control's verdict on each completed trial of one level so far.

    Parameters
    ----------
    trials_by_index : dict of schedule index -> Trial
        The completed trials of one sE level (the latest attempt of each).

    Returns
    -------
    dict of schedule index -> (decision, reasons)
        ``used``, ``repaired`` or ``excluded`` and the reasons (with time spans).
    """
    named = [dataclasses.replace(t, name=str(i)) for i, t in trials_by_index.items()]
    level = assess_level(named)
    out = {}
    for v in level.verdicts:
        spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in v.spans)
        out[int(v.trial)] = (v.decision, "; ".join(v.reasons) + (f" [{spans}]" if spans
                                                                   else ""))
    return out


#: Parameter -> (label, units, the paper's figure).
PARAMETERS = {"Kp": ("Kp", "N", "Figure 4"), "wn_rad_s": ("wn", "rad/s", "Figure 5"),
              "zeta": ("zeta", "", "Figure 6")}


def analysis_dir(session_path: Path) -> Path:
    """``<file stem>-analysis/`` beside the session file (where ``nmsid run`` writes)."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.stem + "-analysis")


def select_models(session_path: Path) -> SelectionView:
    """Identify the finished session, select the parameter curves, write the report.

    Runs ``analysis.run.run_identification`` into :func:`analysis_dir` (parameters.csv,
    model_selection.json, tables.txt, twin.json, the figures) and returns what the results
    panel shows: per parameter, the identified values against sE, the AICc of each
    candidate curve and the selected one.
    """
    out = analysis_dir(session_path)
    outputs = run_identification([Path(session_path)], out, figures=True)
    label = outputs.selection.participants[0]
    params = []
    for name, (title, units, figure) in PARAMETERS.items():
        comp = outputs.selection.comparison(name, label)
        if comp is None:
            continue
        used = [(p.sE, p.value) for p in comp.points if p.used]
        excluded = [(p.sE, p.value) for p in comp.points if not p.used
                    and p.value == p.value]
        fits = [ModelFit(m, float(f.aicc) if f.selectable and f.aicc is not None
                         else float("nan"),
                         tuple(float(c) for c in f.coefficients))
                for m, f in comp.fits.items()]
        params.append(ParameterSelection(
            name=title, units=units,
            sE=np.array([a for a, _ in used]), values=np.array([b for _, b in used]),
            fits=fits, selected=comp.selected or "-", figure=figure,
            trend=comp.trend.text if comp.trend is not None else "",
            excluded_sE=np.array([a for a, _ in excluded]),
            excluded_values=np.array([b for _, b in excluded])))
    return SelectionView(params, saved=[out], tables_text=outputs.tables_text,
                         problems=list(outputs.problems))
