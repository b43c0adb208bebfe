"""The QC verdicts as a table: text for ``nmsid qc``, ``qc.csv``, JSON."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from nmsid.analysis.qc.decide import SessionQC
from nmsid.protocols.printable import escape_controls

QC_COLUMNS = ("participant", "trial", "sE", "repeat", "decision", "reasons", "spans",
              "level_flag")


def rows(qc: SessionQC) -> list[dict]:
    """One dict per judged trial, in session order, with ``QC_COLUMNS``."""
    out = []
    for v in sorted(qc.trials, key=lambda v: v.trial):
        r = v.to_dict()
        r["participant"] = qc.participant
        out.append(r)
    return out


def write_qc_csv(sessions: list[SessionQC], path: str | Path) -> Path:
    """``qc.csv``: every judged trial of every session (columns ``QC_COLUMNS``)."""
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=QC_COLUMNS)
        w.writeheader()
        for qc in sessions:
            for r in rows(qc):
                w.writerow({k: (f"{r[k]:g}" if k == "sE" else escape_controls(r[k])
                                if isinstance(r[k], str) else r[k])
                            for k in QC_COLUMNS})
    return path


def as_json(qc: SessionQC) -> str:
    """The verdicts as JSON (``nmsid qc --json``)."""
    return json.dumps({"participant": qc.participant, "source": qc.source,
                       "counts": qc.counts().to_dict(), "trials": rows(qc),
                       "levels": [{"sE": lv.sE, "n_kept": len(lv.kept), "flag": lv.flag}
                                  for lv in qc.levels],
                       "fatigue": _finite(qc.fatigue.as_dict()) if qc.fatigue else None},
                      indent=2)


def _finite(d: dict) -> dict:
    return {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
            for k, v in d.items()}


def format_table(qc: SessionQC, all_trials: bool = False) -> str:
    """A text table: one line per trial that is not plainly used (all with ``all_trials``),
    then the counts and the flagged levels."""
    lines = [f"{qc.source}: trial quality control ({qc.participant})",
             f"{'trial':6} {'sE':>5} {'rep':>3}  {'decision':9} reasons [spans, s]"]
    shown = 0
    for r in rows(qc):
        if not all_trials and r["decision"] == "used" and not r["reasons"]:
            continue
        shown += 1
        spans = f" [{r['spans']}]" if r["spans"] else ""
        lines.append(f"{r['trial']:6} {r['sE']:5.2f} {r['repeat']:3d}  {r['decision']:9} "
                     f"{r['reasons'] or '-'}{spans}")
    if not shown:
        lines.append("(every trial used as recorded)")
    c = qc.counts()
    lines.append(f"{c.used} used, {c.repaired} repaired, {c.excluded} excluded of {c.total} "
                 "completed trials")
    for lv in qc.levels:
        if lv.flag:
            lines.append(f"sE={lv.sE:g}: {lv.flag}")
    if qc.fatigue is not None and qc.fatigue.significant:
        lines.append(f"{qc.fatigue.sentence()} - each sE's average mixes repeats taken at "
                     "different fatigue")
    return "\n".join(lines)
