"""The headless identification run: session files -> parameters, model selection, twin,
tables and figures in one output folder (what ``nmsid identify`` does).
"""

from __future__ import annotations

import json
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
from nmsid.analysis.report import (
    parameter_table,
    selection_tables,
    write_model_selection_json,
    write_parameters_csv,
    write_scatter_csv,
    write_text,
)
from nmsid.analysis.settings import PARAMETER_NAMES, IdentificationSettings
from nmsid.analysis.twin import Twin, source_entry, twin_from_selection
from nmsid.errors import UserError
from nmsid.progress import Progress
from nmsid.protocols.reprs import counted, html_repr, names, short_repr, to_dataframe
from nmsid.protocols.session_file import Session

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Identification:
    """What an identification run produced (:func:`run_identification`, ``nmsid.identify``).

    Attributes
    ----------
    sessions : list of SessionResult
        Each session's parameters per sE level, in the order given.
    selection : SelectionResult
        The model of each parameter as a function of sE, per participant and averaged.
    files : list of pathlib.Path
        The files written (empty when nothing was kept).
    problems : list of str
        What could not be identified, and why.
    twins : dict of str to Twin
        The twin of each participant (and of ``"average"`` for several).
    tables_text : str
        The tables ``nmsid identify`` prints.
    """

    sessions: list[SessionResult]
    selection: SelectionResult
    files: list[Path] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    twins: dict[str, Twin] = field(default_factory=dict)
    tables_text: str = ""

    @property
    def twin(self) -> Twin | None:
        """The run's twin (``twin.json``): the participant's, or the group average's."""
        label = AVERAGE_LABEL if len(self.sessions) > 1 else \
            (self.selection.participants[0] if self.selection.participants else "")
        return self.twins.get(label)

    def rows(self) -> list[dict]:
        """The ``parameters.csv`` table: one dict per session and sE level."""
        return [row for r in self.sessions for row in r.rows()]

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        return short_repr("Identification", names(self.selection.participants),
                          summary_line(self),
                          f"twins {names(list(self.twins))}" if self.twins else "no twin",
                          counted(len(self.files), "file") if self.files else "")

    _repr_html_ = html_repr


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
                       figures: bool = True, progress: bool = False) -> Identification:
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
    progress : bool
        With several sessions, say on stderr how far the identification is
        (:mod:`nmsid.progress`).

    Returns
    -------
    Identification

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
    bar = Progress(len(sessions), f"identify: {len(sessions)} sessions", unit="session") \
        if progress and len(sessions) > 1 else None
    for src in sessions:
        try:
            res = identify_session(src, s)
        except (UserError, OSError) as exc:  # a file or data problem; bugs propagate
            text = str(exc)  # file errors already start with the file's name
            name = _label(src)
            problems.append((text if text.startswith(name) else f"{name}: {text}")
                            + "; session skipped")
            continue
        finally:
            if bar is not None:
                bar.update()
        results.append(res)
        problems.extend(f"{res.participant}: {p}" for p in res.problems)
    if bar is not None:
        bar.close()
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
    by_code = _sessions_by_participant(results)
    group = len(by_code) > 1
    baselines = {}
    for code, own in by_code.items():
        vals = [lv.data.baseline_N for r in own for lv in r.levels if lv.data is not None]
        baselines[code] = float(np.nanmean(vals)) if vals and np.any(np.isfinite(vals)) \
            else 0.0
    for code, own in by_code.items():
        calibration, note = _participant_calibration(code, own)
        if note:
            problems.append(note)
        try:
            twins[code] = twin_from_selection(selection, code, baseline_N=baselines[code],
                                              calibration=calibration,
                                              source=[sources(r.source) for r in own],
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
        for code, own in by_code.items():
            for res in own:
                name = code if len(own) == 1 else f"{code}_{Path(_label(res.source)).stem}"
                png = plot_level_fits(res, out / f"fit_{_safe_name(name)}.png")
                files += [png, png.with_suffix(".pdf")]
        for name in PARAMETER_NAMES:
            png = plot_parameter_curves(selection, name, out / f"figure_{name}.png",
                                        AVERAGE_LABEL, unit)
            files += [png, png.with_suffix(".pdf")]
    return Identification(results, selection, files, problems, twins, text)


def _sessions_by_participant(results: list[SessionResult]) -> dict[str, list[SessionResult]]:
    """The identified sessions of each participant code, codes in order of first
    appearance (the order of ``select_models``' participants: one participant per code)."""
    by_code: dict[str, list[SessionResult]] = {}
    for r in results:
        by_code.setdefault(r.participant, []).append(r)
    return by_code


def _participant_calibration(code: str, own: list[SessionResult]) -> tuple[dict, str]:
    """The calibration a participant's twin carries: its last session's (the sessions in
    the order given), with a note when its sessions were calibrated differently."""
    calibration = dict(own[-1].calibration or {})
    others = [r for r in own[:-1] if dict(r.calibration or {}) != calibration]
    if not others:
        return calibration, ""
    return calibration, (f"{code}: {len(own)} sessions with different calibrations; the twin "
                         f"carries the last one's ({Path(_label(own[-1].source)).name})")


def _save_twin(twin: Twin, path: Path, problems: list[str]) -> bool:
    """Write a twin; a twin that JSON cannot hold (non-finite curve) becomes a problem."""
    try:
        twin.save(path)
    except TwinFileError as exc:
        problems.append(f"twin not written: {exc}")
        return False
    return True


def analysis_of(session_path) -> Path | None:
    """The latest existing ``<stem>-analysis`` (``-analysis-2``, ...) folder beside the
    session that identified this session alone (the sources its ``model_selection.json``
    names, by file name: the caller knows no trial was added since), else None."""
    path = Path(session_path)
    found = None
    for k in range(1, 10_000):
        folder = path.with_name(path.stem + "-analysis" + (f"-{k}" if k > 1 else ""))
        if not folder.exists():
            break
        try:
            doc = json.loads((folder / "model_selection.json").read_text(encoding="utf-8"))
            names = [Path(str(src)).name for src in doc["sources"]]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if names == [path.name]:
            found = folder
    return found


def summary_line(outputs: Identification) -> str:
    """One line: sessions, levels identified, the lowest fit, problems."""
    n_levels = sum(len(r.levels) for r in outputs.sessions)
    n_ok = sum(1 for r in outputs.sessions for lv in r.levels if lv.fit is not None)
    worst = min((lv.fit.fit_pct for r in outputs.sessions for lv in r.levels
                 if lv.fit is not None and math.isfinite(lv.fit.fit_pct)), default=float("nan"))
    n_people = len(outputs.selection.participants)
    return (f"{len(outputs.sessions)} session(s) of {n_people} participant(s), "
            f"{n_ok}/{n_levels} levels identified, "
            f"lowest fit {worst:.1f} %, {len(outputs.problems)} problem(s)")
