"""Recovery of a session file from its journal after a crash (``nmsid recover``)."""

from __future__ import annotations

import datetime as _dt
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.rig.journal import (PARTIAL_ABORT_REASON, JournalContents, append_event_line,
                               fsync_dir, partial_trial, save_trial_npz, journal_dir,
                               load_trial_npz, read_journal)
from nmsid.protocols.session_file import (Event, SessionFileError, SessionWriter, Trial, read_session,
                                          utc_now, validate_session)

log = logging.getLogger(__name__)


@dataclass
class RecoveryReport:
    """What :func:`recover` did."""

    path: str
    action: str
    """``none`` (file already complete), ``appended`` (missing items added to a good
    file), ``rebuilt`` (a new file from the journal), ``no-calibration`` (the session ended
    before calibration finished: there is no session file to make)."""
    n_trials: int = 0
    n_appended: int = 0
    partial_recovered: bool = False
    partial_samples: int = 0
    damaged_kept_at: str = ""
    problems_before: list[str] = field(default_factory=list)

    def summary(self) -> str:
        if self.action == "none":
            return f"{self.path}: complete ({self.n_trials} trials); nothing to recover"
        if self.action == "no-calibration":
            return (f"{self.path}: the session ended before calibration finished; there is no "
                    "data to recover (resume it to start again)")
        text = {"appended": f"{self.n_appended} trial(s) missing from the file were appended",
                "rebuilt": "rebuilt from the journal"}[self.action]
        text = f"{self.path}: {text}; {self.n_trials} trials in the file"
        if self.partial_recovered:
            text += (f"; the trial in progress was kept as aborted ({self.partial_samples} "
                     "samples)")
        if self.damaged_kept_at:
            text += f"; the damaged file was kept as {self.damaged_kept_at}"
        return text


def _same_trial(a: Trial, b: Trial) -> bool:
    """The journal's trial and the file's are the same, sample for sample."""
    return (abs(float(a.sE) - float(b.sE)) < 1e-12 and int(a.repeat) == int(b.repeat)
            and a.status == b.status
            and all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
                    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N")))


def read_fully(path: Path):
    """(Session, []) if the file validates AND every dataset reads back; else (None,
    problems). A file cut short by a kill can pass the structural checks and still fail
    when its data are read."""
    if not path.exists():
        return None, ["no such file"]
    problems = validate_session(path)
    if problems:
        return None, problems
    try:
        return read_session(path), []
    except Exception as exc:  # h5py raises KeyError / OSError / RuntimeError on damage
        return None, [f"data unreadable ({type(exc).__name__}: {exc})"]


def unique_aside(path: Path, tag: str) -> Path:
    """A free name ``<path>.<tag>-<UTC time>[-k]`` to keep a file aside."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    for k in range(1000):
        cand = path.with_name(f"{path.name}.{tag}-{stamp}" + (f"-{k}" if k else ""))
        if not cand.exists():
            return cand
    raise OSError(f"{path}: cannot find a free name to keep the damaged file aside")


def recover(path: str | os.PathLike) -> RecoveryReport:
    """Bring a session file in line with its journal after a crash.

    Parameters
    ----------
    path : path-like
        The session file (it may be missing, damaged, or complete).

    Returns
    -------
    RecoveryReport

    Raises
    ------
    SessionFileError
        If the file is damaged and there is no journal to rebuild it from.
    """
    path = Path(path)
    jdir = journal_dir(path)
    if not jdir.is_dir():
        s, problems = read_fully(path)
        if s is not None:
            return RecoveryReport(str(path), "none", n_trials=len(s.trials))
        raise SessionFileError(path, f"{problems[0]}; and there is no journal "
                                     f"({jdir.name}) to recover it from")
    if not (jdir / "header.json").exists():  # nothing was ever journaled in it
        s, _ = read_fully(path)
        if s is not None:
            return RecoveryReport(str(path), "none", n_trials=len(s.trials))
        return RecoveryReport(str(path), "no-calibration")
    jc = read_journal(jdir)
    report = RecoveryReport(str(path), "none")
    # 1. the trial in progress becomes an aborted trial of the journal
    if jc.partial_meta is not None:
        seq = int(jc.partial_meta.get("seq", len(jc.trial_files) + 1))
        target = jdir / f"trial-{seq:04d}.npz"
        if seq == len(jc.trial_files) + 1 and not target.exists():
            trial = partial_trial(jc)
            save_trial_npz(target, trial)
            report.partial_recovered = True
            report.partial_samples = trial.n_samples
            append_event_line(jdir, Event(utc_now(), "recovered",
                                           f"trial {seq} (schedule index "
                                           f"{trial.extra_attrs.get('schedule_index', '?')}) "
                                           f"kept as aborted: {PARTIAL_ABORT_REASON}, "
                                           f"{trial.n_samples} samples"))
        for name in ("partial.json", "partial.f64"):
            (jdir / name).unlink(missing_ok=True)
        jc = read_journal(jdir)
    if jc.calibration is None:
        if path.exists() and validate_session(path):
            aside = unique_aside(path, "damaged")
            os.replace(path, aside)
            report.damaged_kept_at = str(aside)
        report.action = "no-calibration"
        return report
    metas = jc.trial_metas()
    report.n_trials = len(metas)
    s, problems = read_fully(path)
    report.problems_before = problems
    if s is not None:
        prefix_ok = (len(s.trials) <= len(metas) and len(s.events) <= len(jc.events)
                     and all(_same_trial(load_trial_npz(p), t)
                             for p, t in zip(jc.trial_files, s.trials)))
        if prefix_ok:
            w = SessionWriter.open(path)
            for p in jc.trial_files[len(s.trials):]:
                w.append_trial(load_trial_npz(p))
                report.n_appended += 1
            w.append_events(jc.events[len(s.events):])
            report.action = "appended" if report.n_appended or report.partial_recovered \
                else "none"
            return report
    # rebuild from the journal into a new file, then swap it in
    tmp = path.with_name(path.name + f".recovering-{os.getpid()}")
    if tmp.exists():
        tmp.unlink()
    _build_from_journal(tmp, jc)
    if path.exists():
        aside = unique_aside(path, "damaged")
        os.replace(path, aside)
        report.damaged_kept_at = str(aside)
    os.replace(tmp, path)
    fsync_dir(path.parent)
    report.action = "rebuilt"
    log.warning("%s", report.summary())
    return report


def create_from_header(path: Path, header: dict) -> SessionWriter:
    """Create the HDF5 file with the root attributes the journal header recorded."""
    return SessionWriter.create(
        path, participant=header["participant"], created_utc=header["created_utc"],
        software=header.get("software"), config_json=header.get("config_json"),
        seed=header.get("seed"), backend=header.get("backend"),
        extra_attrs=header.get("extra_attrs") or {})


def _build_from_journal(path: Path, jc: JournalContents) -> None:
    """Write a complete session file at ``path`` from the journal alone."""
    w = create_from_header(path, jc.header)
    w.write_calibration(jc.calibration)
    for p in jc.trial_files:
        w.append_trial(load_trial_npz(p))
    w.append_events(jc.events)
    with open(path, "rb+") as fh:
        os.fsync(fh.fileno())
