"""The group analysis of a study: model selection across participants (the paper's
Tables 1-9, reusing ``analysis.model_selection``) and the group gap summary, written as
CSV and JSON.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.analysis.model_selection import (
    AVERAGE_LABEL,
    ParticipantParameters,
    SelectionResult,
    select_models,
)
from nmsid.analysis.report import selection_tables, write_model_selection_json
from nmsid.analysis.settings import PARAMETER_NAMES, IdentificationSettings


@dataclass
class GroupResult:
    """Group outputs: the selection (None if no session was identified), the gap
    summary and the files written."""

    selection: SelectionResult | None
    gap: dict
    tables_text: str
    files: list[Path] = field(default_factory=list)
    joints: dict[str, GroupResult] = field(default_factory=dict)
    """Sessions of several joints: the group analysis of each joint on its own (its files
    in ``group-<joint>/``); empty for a study of one joint (the files at the top)."""
    note: str = ""
    """One line when the group analysis was split per joint."""
    unit: str = "N"
    """The unit of Kp (per unit rE) in the tables: the joint's."""


def _nan(v) -> float:
    return float("nan") if v is None else float(v)


def participants_of(results: list[dict], overrides: dict[str, str]) -> list[ParticipantParameters]:
    """ParticipantParameters of the identified sessions (participant codes overridden by
    the study's ``[participants]`` table, keyed by file stem)."""
    people = []
    for r in results:
        if not r.get("ok"):
            continue
        code = overrides.get(Path(r["path"]).stem, r["participant"])
        people.append(ParticipantParameters(
            code, np.asarray(r["sE"], dtype=float),
            {k: np.array([_nan(v) for v in r["values"][k]]) for k in PARAMETER_NAMES}))
    return people


def gap_summary(results: list[dict]) -> dict:
    """Which effects explain the sim-to-real gap, how often, and how far they shrink it.

    ``best_effect``: per effect, the sessions where it ranked first and the median held-out
    shrink of the best (augmented) model there; ``supported``: per effect, in how many
    sessions it was supported on its own and its median shrink of the held-out NRMSE.
    """
    diagnosed = [r for r in results if r.get("gap")]
    best: dict[str, list[float]] = {}
    supported: dict[str, list[float]] = {}
    for r in diagnosed:
        g = r["gap"]
        best.setdefault(g["best_effect"], []).append(_nan(g["heldout"].get("shrink_pct")))
        for s in g["supported"]:
            supported.setdefault(s["effect"], []).append(_nan(s["shrink_pct"]))

    def med(xs):
        xs = [x for x in xs if math.isfinite(x)]
        return statistics.median(xs) if xs else None

    nominal = [_nan(r["gap"]["heldout"].get("nominal_nrmse_pct")) for r in diagnosed]
    augmented = [_nan(r["gap"]["heldout"].get("augmented_nrmse_pct")) for r in diagnosed]
    return {
        "n_sessions_diagnosed": len(diagnosed),
        "best_effect": {k: {"sessions": len(v), "median_shrink_pct": med(v)}
                        for k, v in sorted(best.items(), key=lambda kv: -len(kv[1]))},
        "supported": {k: {"sessions": len(v), "median_shrink_pct": med(v)}
                      for k, v in sorted(supported.items(), key=lambda kv: -len(kv[1]))},
        "median_nominal_heldout_nrmse_pct": med(nominal),
        "median_augmented_heldout_nrmse_pct": med(augmented),
    }


def _write_csv(path: Path, header: list[str], rows: list[list]) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _cell(v):
    return "" if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def write_group(results: list[dict], out_dir: Path, settings: IdentificationSettings,
                overrides: dict[str, str]) -> GroupResult:
    """Run the group analysis and write its CSV/JSON files into ``out_dir``."""
    out = Path(out_dir)
    files: list[Path] = []
    files.append(_write_csv(
        out / "sessions.csv",
        ["session", "participant", "ok", "levels", "levels_identified", "lowest_fit_pct",
         "gap_best_effect", "gap_shrink_pct", "elapsed_s", "peak_rss_MB", "error"],
        [[r["path"], overrides.get(Path(r["path"]).stem, r.get("participant", "")),
          r.get("ok"), r.get("levels", ""), r.get("levels_identified", ""),
          _cell(r.get("lowest_fit_pct")),
          (r.get("gap") or {}).get("best_effect", ""),
          _cell((r.get("gap") or {}).get("heldout", {}).get("shrink_pct")),
          f"{r['elapsed_s']:.2f}", f"{r['peak_rss_MB']:.0f}", r.get("error", "")]
         for r in results]))
    gap = gap_summary(results)
    (out / "gap_summary.json").write_text(json.dumps(gap, indent=1) + "\n", encoding="utf-8")
    files.append(out / "gap_summary.json")
    by_joint: dict[tuple[str, str], list[dict]] = {}
    for r in results:
        if r.get("ok"):
            by_joint.setdefault((r.get("joint", "elbow"), r.get("measured_unit", "N")),
                                []).append(r)
    if len(by_joint) <= 1:
        joint, unit = next(iter(by_joint), ("elbow", "N"))
        g = _selection_files(results, out, settings, overrides, joint, unit)
        return GroupResult(g.selection, gap, g.tables_text, files + g.files, unit=unit)
    # AICc sums over an elbow and a knee mean nothing: each joint's group on its own
    parts = {}
    for (joint, unit), rs in sorted(by_joint.items()):
        sub = out / f"group-{joint}"
        sub.mkdir(exist_ok=True)
        parts[joint] = _selection_files(rs, sub, settings, overrides, joint, unit)
        files += parts[joint].files
    note = (f"sessions of {len(parts)} joints ("
            + ", ".join(f"{j}: {len(rs)} in {u}" for (j, u), rs in sorted(by_joint.items()))
            + "): the group analysis is split per joint into "
            + ", ".join(f"group-{j}/" for j in parts) + " (AICc sums pool one joint; "
            "docs/joints.md)")
    text = "\n\n".join(f"=== {j} ===\n{g.tables_text}" for j, g in parts.items())
    return GroupResult(None, gap, text, files, joints=parts, note=note)


def _selection_files(results: list[dict], out: Path, settings: IdentificationSettings,
                     overrides: dict[str, str], joint: str, unit: str) -> GroupResult:
    """Model selection of the identified sessions of one joint (the paper's Tables 1-9)
    and its CSV / JSON / text files in ``out``."""
    files: list[Path] = []
    people = participants_of(results, overrides)
    if not people:
        return GroupResult(None, {}, "no session was identified", files, unit=unit)
    selection = select_models(people, settings)
    files.append(write_model_selection_json(
        selection, out / "model_selection.json",
        extra={"sources": [r["path"] for r in results if r.get("ok")], "joint": joint,
               "measured_unit": unit}))
    labels = [AVERAGE_LABEL] + selection.participants
    aicc_rows, sel_rows = [], []
    for name in PARAMETER_NAMES:
        for label in labels:
            c = selection.comparison(name, label)
            if c is None:
                continue
            for m in settings.models:
                f = c.fits.get(m)
                aicc_rows.append([name, label, m, _cell(f.aicc) if f and f.selectable else ""])
            sel_rows.append([name, label, c.selected or "",
                             c.trend.text if c.selected and c.trend is not None
                             else "no model selectable"])
    files.append(_write_csv(out / "aicc.csv", ["parameter", "participant", "model", "aicc"],
                            aicc_rows))
    files.append(_write_csv(out / "selected_models.csv",
                            ["parameter", "participant", "selected_model", "trend"], sel_rows))
    files.append(_write_csv(
        out / "aicc_sums.csv", ["parameter", "model", "aicc_sum", "participants_counted"],
        [[name, m, _cell(selection.aicc_sums[name][m]), selection.aicc_sum_counts[name][m]]
         for name in PARAMETER_NAMES for m in settings.models]))
    text = selection_tables(selection, unit)
    (out / "tables.txt").write_text(text + "\n", encoding="utf-8")
    files.append(out / "tables.txt")
    return GroupResult(selection, {}, text, files, unit=unit)
