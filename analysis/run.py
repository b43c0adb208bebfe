"""The headless identification run: session files -> parameters, model selection, twin,
tables and figures in one output folder (what ``nmsid identify`` does).
"""

from __future__ import annotations

import logging
import math
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.analysis.errors import IdentificationError, TwinFileError
from nmsid.analysis.identify import SessionResult, identify_session
from nmsid.analysis.model_selection import AVERAGE_LABEL, SelectionResult, select_models
from nmsid.analysis.qc.table import write_qc_csv
from nmsid.analysis.report import (parameter_table, selection_tables, write_model_selection_json,
                                   write_parameters_csv, write_scatter_csv, write_text)
from nmsid.analysis.settings import PARAMETER_NAMES, IdentificationSettings
from nmsid.analysis.twin import Twin, source_entry, twin_from_selection
from nmsid.errors import UserError
from nmsid.protocols.session_file import Session

logger = logging.getLogger(__name__)


@dataclass
class RunOutputs:
    """What a run produced."""

    sessions: list[SessionResult]
    selection: SelectionResult
    files: list[Path] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    twins: dict[str, Twin] = field(default_factory=dict)
    tables_text: str = ""


def _label(src) -> str:
    """A session's file name, whether given as a path or as a session read already."""
    return str(src.path) if isinstance(src, Session) else str(src)


def _safe_name(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label)


class _SourceEntries:
    """Each session file's twin ``source`` entry (name and SHA-256), hashed in a thread
    started before the fit: hashlib releases the GIL, so reading ~100 MB costs no wall time
    beside the identification."""

    def __init__(self, sessions):
        self._paths = [str(Path(_label(s))) for s in sessions]
        self._entries: dict[str, dict | str] = {}
        self._thread = threading.Thread(target=self._hash_all, daemon=True,
                                        name="nmsid-source-hash")
        self._thread.start()

    def _hash_all(self) -> None:
        for p in self._paths:
            try:
                self._entries[p] = source_entry(p)
            except OSError:       # unreadable: identify reports it; name the file only
                self._entries[p] = {"file": Path(p).name}

    def __call__(self, source: str) -> dict | str:
        self._thread.join()
        return self._entries.get(str(source)) or source_entry(source)


def run_identification(sessions, out_dir: str | os.PathLike,
                       settings: IdentificationSettings | None = None, *,
                       figures: bool = True) -> RunOutputs:
    """Identify one or several sessions and write every output into ``out_dir``.

    Parameters
    ----------
    sessions : sequence of path-like or protocols.session_file.Session
        One session: that participant's analysis. Several: also the group analysis
        (participant averages, AICc sums).
    out_dir : path-like
        Created if missing. Receives ``parameters.csv``, ``model_selection.json``,
        ``tables.txt``, ``problems.txt``, ``twin.json`` (the participant's, or the group
        average's; plus ``twin_<participant>.json`` each in a group run) and, unless
        ``figures`` is False, ``fit_<participant>.png`` and ``figure_<parameter>.png``.
    settings : IdentificationSettings, optional
    figures : bool
        Draw the figures (needs matplotlib).

    Returns
    -------
    RunOutputs

    Raises
    ------
    IdentificationError
        If no session could be read at all (each unreadable file is otherwise reported
        and skipped).
    """
    s = settings or IdentificationSettings()
    sources = _SourceEntries(sessions)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results: list[SessionResult] = []
    problems: list[str] = []
    for src in sessions:
        try:
            res = identify_session(src, s)
        except (UserError, OSError) as exc:  # a file or data problem; bugs propagate
            text = str(exc)  # file errors already start with the file's name
            name = _label(src)
            problems.append((text if text.startswith(name) else f"{name}: {text}")
                            + "; session skipped")
            continue
        results.append(res)
        problems.extend(f"{res.participant}: {p}" for p in res.problems)
    if not results:
        raise IdentificationError("no session could be analysed: " + " | ".join(problems))
    measured = sorted({(r.joint, r.quantity, r.unit) for r in results})
    if len(measured) > 1:   # AICc sums over an elbow and a knee mean nothing
        raise IdentificationError(
            "the sessions are of different joints or quantities ("
            + ", ".join(f"{j} {q} in {u}" for j, q, u in measured) + "): a group analysis "
            "pools one joint; identify each joint's sessions on their own (docs/joints.md)")
    joint, quantity, unit = measured[0]
    files = [write_parameters_csv(results, out / "parameters.csv")]
    if any(r.qc is not None for r in results):
        files.append(write_qc_csv([r.qc for r in results if r.qc is not None],
                                  out / "qc.csv"))
    if any(r.scatter is not None for r in results):
        files.append(write_scatter_csv(results, out / "scatter.csv"))
    selection = select_models(results, s)
    problems.extend(selection.problems)
    files.append(write_model_selection_json(
        selection, out / "model_selection.json",
        extra={"sources": [r.source for r in results], "joint": joint,
               "measured_quantity": quantity, "measured_unit": unit}))

    twins: dict[str, Twin] = {}
    group = len(results) > 1
    baselines = {}
    for label, res in zip(selection.participants, results):
        vals = [lv.data.baseline_N for lv in res.levels if lv.data is not None]
        baselines[label] = float(np.nanmean(vals)) if vals and np.any(np.isfinite(vals)) \
            else 0.0
    targets = [(label, res) for label, res in zip(selection.participants, results)]
    for label, res in targets:
        try:
            twins[label] = twin_from_selection(selection, label, baseline_N=baselines[label],
                                               calibration=res.calibration,
                                               source=[sources(res.source)],
                                               measured=measured[0])
        except IdentificationError as exc:
            problems.append(f"twin not written: {exc}")
    if group:
        try:
            twins[AVERAGE_LABEL] = twin_from_selection(
                selection, AVERAGE_LABEL, baseline_N=float(np.mean(list(baselines.values()))),
                source=[sources(r.source) for r in results], measured=measured[0])
        except IdentificationError as exc:
            problems.append(f"twin not written: {exc}")
        for label in selection.participants:
            if label in twins:
                path = out / f"twin_{_safe_name(label)}.json"
                if _save_twin(twins[label], path, problems):
                    files.append(path)
        main_twin = twins.get(AVERAGE_LABEL)
    else:
        main_twin = twins.get(selection.participants[0])
    if main_twin is not None and _save_twin(main_twin, out / "twin.json", problems):
        files.append(out / "twin.json")

    text = "\n\n".join(parameter_table(r) for r in results) + "\n\n" + \
        selection_tables(selection, unit)
    files.append(write_text(text, out / "tables.txt"))
    files.append(write_text("\n".join(problems) if problems else "no problems",
                            out / "problems.txt"))
    if figures:
        # imported here: a run without figures (`nmsid identify --no-figures`) never
        # loads the drawing code
        from nmsid.analysis.figures import plot_level_fits, plot_parameter_curves
        for label, res in zip(selection.participants, results):
            files.append(plot_level_fits(res, out / f"fit_{_safe_name(label)}.png"))
        for name in PARAMETER_NAMES:
            files.append(plot_parameter_curves(selection, name, out / f"figure_{name}.png",
                                               AVERAGE_LABEL, unit))
    return RunOutputs(results, selection, files, problems, twins, text)


def _save_twin(twin: Twin, path: Path, problems: list[str]) -> bool:
    """Write a twin; a twin that JSON cannot hold (non-finite curve) becomes a problem."""
    try:
        twin.save(path)
    except TwinFileError as exc:
        problems.append(f"twin not written: {exc}")
        return False
    return True


def summary_line(outputs: RunOutputs) -> str:
    n_levels = sum(len(r.levels) for r in outputs.sessions)
    n_ok = sum(1 for r in outputs.sessions for lv in r.levels if lv.fit is not None)
    worst = min((lv.fit.fit_pct for r in outputs.sessions for lv in r.levels
                 if lv.fit is not None and math.isfinite(lv.fit.fit_pct)), default=float("nan"))
    return (f"{len(outputs.sessions)} session(s), {n_ok}/{n_levels} levels identified, "
            f"lowest fit {worst:.1f} %, {len(outputs.problems)} problem(s)")
