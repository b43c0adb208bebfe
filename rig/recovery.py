"""Recovery of a session file from its journal after a crash (``nmsid recover``).

Recovery is a writer: it takes the session's lock (refused, naming the process, while a
run writes the session), salvages every readable journal entry (an unreadable one, e.g. a
``trial-0005.npz`` truncated by a kill, is reported and kept aside in the journal, the
later ones move up), and publishes the file in one atomic step. It leaves no temporary
file behind in any outcome: the temp files and half-removed journals of earlier,
killed writers are removed first (safe: they hold the lock).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.protocols.errors import DiskFullError
from nmsid.protocols.session_file import (Event, SessionFileError, SessionWriter, Trial,
                                          read_session, utc_now, validate_session)
from nmsid.protocols.session_lock import SessionLock
from nmsid.protocols.session_publish import (SPACE_MARGIN_BYTES, free_bytes, fsync_dir,
                                             remove_stale_temps)
from nmsid.rig.journal import (PARTIAL_ABORT_REASON, JournalContents, JournalEntryError,
                               append_event_line, journal_dir, load_trial_meta, load_trial_npz,
                               partial_trial, read_journal, save_trial_npz)

log = logging.getLogger(__name__)

_TRIAL_FILE = re.compile(r"^trial-(\d{4,})\.npz$")


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
    unreadable: list[str] = field(default_factory=list)
    """Journal entries that could not be read: ``"trial-0005.npz (BadZipFile: ...), kept
    as ..."``."""
    orphans: list[str] = field(default_factory=list)
    """Journals in the folder whose session file is missing (a file renamed before
    recovery leaves its journal behind under the old name)."""
    leftovers_removed: int = 0

    def summary(self) -> str:
        if self.action == "none":
            text = f"{self.path}: complete ({self.n_trials} trials); nothing to recover"
        elif self.action == "no-calibration":
            text = (f"{self.path}: the session ended before calibration finished; there is "
                    "no data to recover (resume it to start again)")
        else:
            text = {"appended": f"{self.n_appended} trial(s) missing from the file were "
                                "appended",
                    "rebuilt": "rebuilt from the journal"}[self.action]
            text = f"{self.path}: {text}; {self.n_trials} trials in the file"
        if self.partial_recovered:
            text += (f"; the trial in progress was kept as aborted ({self.partial_samples} "
                     "samples)")
        if self.damaged_kept_at:
            text += f"; the damaged file was kept as {self.damaged_kept_at}"
        if self.unreadable:
            text += (f"; {len(self.unreadable)} unreadable journal entr"
                     f"{'y' if len(self.unreadable) == 1 else 'ies'} skipped: "
                     + "; ".join(self.unreadable))
        if self.orphans:
            text += ("; note: " + "; ".join(self.orphans))
        return text


def _same_trial(a: Trial, b: Trial) -> bool:
    """The journal's trial and the file's are the same, sample for sample."""
    return (abs(float(a.sE) - float(b.sE)) < 1e-12 and int(a.repeat) == int(b.repeat)
            and a.status == b.status
            and all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
                    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N")))


def read_fully(path: Path):
    """(Session, []) if the file validates AND every dataset reads back (checksums
    verified); else (None, problems)."""
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
        if not os.path.lexists(cand):
            return cand
    raise SessionFileError(path, "cannot find a free name to keep a damaged file aside")


def remove_leftovers(path: str | os.PathLike) -> int:
    """Remove what killed writers of this session left: ``<file>.writing-<pid>`` /
    ``.recovering-<pid>`` temp files, ``<file>.journal.done-<pid>`` (a journal being
    removed after a clean end) and ``<file>.journal.tmp-<pid>`` (a journal being built),
    and ``*.tmp`` files inside the journal. Call only while holding the session's lock.

    Returns
    -------
    int
        How many were removed.
    """
    path = Path(path)
    n = len(remove_stale_temps(path))
    jdir = journal_dir(path)
    try:
        names = os.listdir(path.parent)
    except OSError:
        names = []
    pat = re.compile(re.escape(jdir.name) + r"\.(done|tmp)-\d+")
    for name in names:
        if pat.fullmatch(name):
            shutil.rmtree(path.parent / name, ignore_errors=True)
            n += 1
    if jdir.is_dir():
        for p in jdir.iterdir():
            if p.name.endswith(".tmp"):
                p.unlink(missing_ok=True)
                n += 1
    return n


def orphan_journals(path: Path) -> list[str]:
    """Journals beside ``path`` whose own session file is missing, each described in
    words (with a hint when it matches this file's participant and start time)."""
    out = []
    try:
        entries = sorted(os.listdir(path.parent))
    except OSError:
        return out
    mine = None
    try:
        s = read_session(path, load_data=False)
        mine = (s.participant, s.created_utc)
    except (SessionFileError, OSError):
        pass
    for name in entries:
        if not name.endswith(".journal") or name == journal_dir(path).name:
            continue
        owner = path.parent / name[: -len(".journal")]
        if owner.exists() or not (path.parent / name).is_dir():
            continue
        try:
            header = json.loads((path.parent / name / "header.json").read_text("utf-8"))
        except (OSError, ValueError):
            header = {}
        who = (header.get("participant"), header.get("created_utc"))
        if mine is not None and who == mine:
            out.append(f"{path.parent / name} is this file's journal (same participant and "
                       f"start time) left under its old name {owner.name}: rename the file "
                       f"back to {owner.name} and run `nmsid recover {owner}`")
        else:
            out.append(f"{path.parent / name} is the journal of a missing session file "
                       f"{owner.name} (participant {who[0]}, started {who[1]}); if this file "
                       "was renamed from it, rename it back and run `nmsid recover` on it")
    return out


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
    SessionLockedError
        If another process writes the session (names it).
    DiskFullError
        If the folder lacks the space to recover (names the need and the free space);
        nothing is changed then.
    SessionFileError
        If the file is damaged and there is no journal to rebuild it from.
    """
    path = Path(path)
    lock = SessionLock.acquire(path, "nmsid recover")
    try:
        removed = remove_leftovers(path)
        report = _recover_locked(path)
        report.leftovers_removed = removed
        return report
    finally:
        lock.release()


def _recover_locked(path: Path) -> RecoveryReport:
    jdir = journal_dir(path)
    if not jdir.is_dir():
        s, problems = read_fully(path)
        if s is not None:
            return RecoveryReport(str(path), "none", n_trials=len(s.trials),
                                  orphans=orphan_journals(path))
        orphans = orphan_journals(path)
        raise SessionFileError(path, f"{problems[0]}; and there is no journal "
                                     f"({jdir.name}) to recover it from"
                               + (f"; note: {'; '.join(orphans)}" if orphans else ""))
    if not (jdir / "header.json").exists():  # nothing was ever journaled in it
        s, _ = read_fully(path)
        if s is not None:
            return RecoveryReport(str(path), "none", n_trials=len(s.trials))
        return RecoveryReport(str(path), "no-calibration")
    report = RecoveryReport(str(path), "none")
    jc = read_journal_salvaged(jdir, report)
    # 1. the trial in progress becomes an aborted trial of the journal
    if jc.partial_meta is not None:
        seq = int(jc.partial_meta.get("seq", len(jc.trial_files) + 1))
        target = jdir / f"trial-{seq:04d}.npz"
        if seq == len(jc.trial_files) + 1 and not target.exists():
            trial = partial_trial(jc)
            _check_space(path, jc, extra_bytes=3 * _trial_bytes(trial))
            save_trial_npz(target, trial)
            report.partial_recovered = True
            report.partial_samples = trial.n_samples
            try:
                append_event_line(jdir, Event(utc_now(), "recovered",
                                              f"trial {seq} (schedule index "
                                              f"{trial.extra_attrs.get('schedule_index', '?')}"
                                              f") kept as aborted: {PARTIAL_ABORT_REASON}, "
                                              f"{trial.n_samples} samples"))
            except OSError:
                pass
        for name in ("partial.json", "partial.f64"):
            (jdir / name).unlink(missing_ok=True)
        jc = read_journal_salvaged(jdir, report)
    if jc.calibration is None:
        if jc.calibration_error:
            s, _ = read_fully(path)
            if s is None:
                raise SessionFileError(jdir / "calibration.npz", jc.calibration_error
                                       + "; and the session file has none readable")
            jc.calibration = s.calibration
        else:
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
        journal_trials = [load_trial_npz(p) for p in jc.trial_files[:len(s.trials)]]
        prefix_ok = (len(s.trials) <= len(metas) and len(s.events) <= len(jc.events)
                     and all(_same_trial(a, b) for a, b in zip(journal_trials, s.trials)))
        if prefix_ok:
            missing = [load_trial_npz(p) for p in jc.trial_files[len(s.trials):]]
            new_events = jc.events[len(s.events):]
            if missing or new_events:
                w = SessionWriter.open(path)
                w.append_trials(missing, new_events) if missing else \
                    w.append_events(new_events)
            report.n_appended = len(missing)
            report.action = "appended" if missing or report.partial_recovered else "none"
            return report
    # rebuild from the journal in memory, then publish it in one step
    w = _build_from_journal(path, jc)
    aside = None
    if os.path.lexists(path):
        aside = unique_aside(path, "damaged")
        os.link(path, aside)  # keep the damaged file (no copy, no space needed)
    try:
        w.publish("rebuilding it from the journal")
    except BaseException:
        if aside is not None:
            os.unlink(aside)
        raise
    fsync_dir(path.parent)
    report.damaged_kept_at = str(aside) if aside is not None else ""
    report.action = "rebuilt"
    log.warning("%s", report.summary())
    return report


def read_journal_salvaged(jdir: Path, report: RecoveryReport) -> JournalContents:
    """Read the journal after moving unreadable trial entries aside (``unreadable-
    trial-0005.npz``) and renumbering the later ones, so the journal is again
    ``trial-0001 ...`` without gaps. Idempotent, and safe to interrupt: each step is one
    rename. Each entry set aside is added to ``report.unreadable``."""
    files = sorted((p for p in jdir.iterdir() if _TRIAL_FILE.match(p.name)),
                   key=lambda p: int(_TRIAL_FILE.match(p.name).group(1)))
    for p in files:
        try:
            load_trial_meta(p)
            load_trial_npz(p)
        except JournalEntryError as exc:
            aside = unique_aside(jdir / f"unreadable-{p.name}", "at")
            os.replace(p, aside)
            report.unreadable.append(f"{p.name} ({exc.problem.split('(', 1)[-1].rstrip(')')})"
                                     f", kept as {aside.name}")
    files = sorted((p for p in jdir.iterdir() if _TRIAL_FILE.match(p.name)),
                   key=lambda p: int(_TRIAL_FILE.match(p.name).group(1)))
    for i, p in enumerate(files):
        want = jdir / f"trial-{i + 1:04d}.npz"
        if p != want:
            os.replace(p, want)
            _renumber_partial(jdir, p, want)
    fsync_dir(jdir)
    return read_journal(jdir)


def _renumber_partial(jdir: Path, old: Path, new: Path) -> None:
    """Keep ``partial.json``'s ``seq`` pointing just past the last journaled trial."""
    pj = jdir / "partial.json"
    if not pj.exists():
        return
    try:
        meta = json.loads(pj.read_text("utf-8"))
        n_old = int(_TRIAL_FILE.match(old.name).group(1))
        n_new = int(_TRIAL_FILE.match(new.name).group(1))
        if int(meta.get("seq", 0)) == n_old + 1:
            meta["seq"] = n_new + 1
            pj.write_text(json.dumps(meta), "utf-8")
    except (OSError, ValueError, AttributeError):
        pass


def _trial_bytes(trial: Trial) -> int:
    return sum(np.asarray(getattr(trial, k)).nbytes for k in
               ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync")
               if getattr(trial, k) is not None)


def _check_space(path: Path, jc: JournalContents, extra_bytes: int = 0) -> None:
    """Refuse (changing nothing) unless the folder holds what recovery may write: the
    new trial in the journal, and a rebuilt file as large as the whole journal."""
    journal_bytes = sum(p.stat().st_size for p in jc.trial_files)
    need = journal_bytes + extra_bytes + 2 * SPACE_MARGIN_BYTES
    free = free_bytes(path.parent)
    if free < need:
        raise DiskFullError(path, need, free, "recovering it")


def create_from_header(path: Path, header: dict) -> SessionWriter:
    """Create the HDF5 file with the root attributes the journal header recorded."""
    return SessionWriter.create(path, **_header_kwargs(header))


def _header_kwargs(header: dict) -> dict:
    return dict(participant=header["participant"], created_utc=header["created_utc"],
                software=header.get("software"), config_json=header.get("config_json"),
                seed=header.get("seed"), backend=header.get("backend"),
                extra_attrs=header.get("extra_attrs") or {})


def _build_from_journal(path: Path, jc: JournalContents) -> SessionWriter:
    """A writer holding a complete session file built from the journal alone, in memory
    (not yet published)."""
    try:
        image = SessionWriter.new_image(path, **_header_kwargs(jc.header))
    except (KeyError, TypeError) as exc:
        raise SessionFileError(journal_dir(path) / "header.json",
                               f"journal header lacks {exc}") from None
    w = SessionWriter(path, image=image)
    w.deferred = True
    w.write_calibration(jc.calibration)
    w.append_trials([load_trial_npz(p) for p in jc.trial_files], jc.events)
    return w
