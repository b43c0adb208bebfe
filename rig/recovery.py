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

from nmsid.protocols.errors import DiskFullError, SessionLockedError
from nmsid.protocols.session_file import (
    Calibration,
    Event,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    utc_now,
    validate_session,
)
from nmsid.protocols.session_lock import SessionLock
from nmsid.protocols.session_model import (
    _DAMAGE_ERRORS,
    CALIBRATION_ATTRS,
    OPTIONAL_SIGNALS,
    TRIAL_DATASETS,
    _as_str,
    _h5py,
    _trial_names,
)
from nmsid.protocols.session_publish import (
    SPACE_MARGIN_BYTES,
    free_bytes,
    fsync_dir,
    remove_stale_temps,
    rename_retrying,
)
from nmsid.protocols.session_reader import _read_events, _read_trial
from nmsid.protocols.session_state import session_state
from nmsid.rig.journal import (
    PARTIAL_ABORT_REASON,
    JournalContents,
    JournalEntryError,
    append_event_line,
    journal_dir,
    json_default,
    load_trial_meta,
    load_trial_npz,
    partial_trial,
    read_journal,
    save_calibration,
    save_trial_npz,
    trial_digest,
    write_durable,
)

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
    """Journal entries that could not be read, each with its outcome: ``"trial-0005.npz
    (unreadable: BadZipFile: ...): kept from the file's t005"`` (or ``...: lost``)."""
    orphans: list[str] = field(default_factory=list)
    """Journals in the folder whose session file is missing (a file renamed before
    recovery leaves its journal behind under the old name)."""
    leftovers_removed: int = 0
    header_rebuilt: str = ""
    """How a missing or damaged journal ``header.json`` was rebuilt (empty if it was
    readable)."""
    deleted: list[str] = field(default_factory=list)
    """Journal entries missing from the numbering, each with its outcome (kept from the
    file, or lost)."""
    lost: list[str] = field(default_factory=list)
    """Names of journal entries whose trial is neither readable there nor in the file."""
    conflicts: list[str] = field(default_factory=list)
    """Positions where the journal and the file hold different trials (both kept)."""
    calibration_restored: str = ""
    """A journal ``calibration.npz`` that could not be read: what was wrong, where it was
    kept aside and that the session file's calibration replaced it (empty otherwise)."""

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
        if self.header_rebuilt:
            text += f"; {self.header_rebuilt}"
        if self.calibration_restored:
            text += f"; {self.calibration_restored}"
        if self.unreadable:
            text += (f"; {len(self.unreadable)} unreadable journal entr"
                     f"{'y' if len(self.unreadable) == 1 else 'ies'} (kept aside as "
                     "unreadable-<name>.at-<time>): " + "; ".join(self.unreadable))
        if self.deleted:
            text += "; deleted journal entries: " + "; ".join(self.deleted)
        if self.lost:
            text += (f"; {len(self.lost)} trial(s) lost (in no readable copy; `run "
                     "--resume` runs them again)")
        if self.conflicts:
            text += "; " + "; ".join(self.conflicts)
        if self.orphans:
            text += ("; note: " + "; ".join(self.orphans))
        return text


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


def _restore_calibration(jdir: Path, error: str, calibration: Calibration) -> str:
    """The journal's unreadable ``calibration.npz`` kept aside and replaced by the session
    file's calibration (the published copy of the same values), so a resume continues.
    Returns the report's words."""
    damaged = jdir / "calibration.npz"
    aside = unique_aside(damaged, "damaged")
    if damaged.exists():
        rename_retrying(damaged, aside)
    save_calibration(damaged, calibration)
    return (f"the journal's calibration.npz could not be read ({error}); kept as "
            f"{aside.name}, the calibration taken from the session file")


def unique_aside(path: Path, tag: str) -> Path:
    """A free name ``<path>.<tag>-<UTC time>[-k]`` to keep a file aside."""
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    for k in range(1000):
        cand = path.with_name(f"{path.name}.{tag}-{stamp}" + (f"-{k}" if k else ""))
        if not os.path.lexists(cand):
            return cand
    raise SessionFileError(path, "cannot find a free name to keep a damaged file aside")


def remove_leftovers(path: str | os.PathLike) -> int:
    """Remove what killed writers of this session left: ``<file>.writing-<pid>`` /
    ``.recovering-<pid>`` temp files, ``<file>.journal.done-<pid>`` (a journal being
    removed after a clean end), ``<file>.journal.tmp-<pid>`` (a journal being built), an
    empty ``<file>.journal.headerless-<time>`` (older versions set a journal without
    header aside; one with entries is kept) and ``*.tmp`` files inside the journal. Call
    only while holding the session's lock.

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
    headerless = re.compile(re.escape(jdir.name) + r"\.headerless-[0-9TZ-]+")
    for name in names:
        if pat.fullmatch(name) or headerless.fullmatch(name) and \
                not _journal_holds_data(path.parent / name):
            # .done: the file was checked complete before the rename; .tmp: built aside,
            # never the journal; a headerless journal without entries holds nothing
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
    out: list[str] = []
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
    report = RecoveryReport(str(path), "none")
    if not _header_readable(jdir):
        if not _journal_holds_data(jdir):  # nothing was ever journaled in it: remove it
            shutil.rmtree(jdir, ignore_errors=True)
            s, _ = read_fully(path)
            if s is not None:
                return RecoveryReport(str(path), "none", n_trials=len(s.trials))
            return RecoveryReport(str(path), "no-calibration")
        report.header_rebuilt = rebuild_header(path, jdir)
    jc = read_journal(jdir, allow_gaps=True)
    # 1. the trial in progress becomes an aborted trial of the journal
    if jc.partial_meta is not None:
        last = max((_entry_number(p) for p in _entries(jdir)), default=0)
        seq = int(jc.partial_meta.get("seq", last + 1))
        target = jdir / f"trial-{seq:04d}.npz"
        if seq == last + 1 and not target.exists():
            trial = partial_trial(jc)
            _check_space(path, jc, extra_bytes=3 * _trial_bytes(trial))
            save_trial_npz(target, trial)
            report.partial_recovered = True
            report.partial_samples = trial.n_samples
            try:
                append_event_line(jdir, Event(utc_now(), "recovered",
                                              f"trial t{seq:03d} kept as aborted: "
                                              f"{PARTIAL_ABORT_REASON}, "
                                              f"{trial.n_samples} samples"))
            except OSError:
                pass
        for name in ("partial.json", "partial.f64"):
            (jdir / name).unlink(missing_ok=True)
        jc = read_journal(jdir, allow_gaps=True)
    fs = salvage_file(path)
    if jc.calibration is None:
        if jc.calibration_error:
            if fs.calibration is None:
                raise SessionFileError(jdir / "calibration.npz", jc.calibration_error
                                       + "; and the session file has none readable")
            jc.calibration = fs.calibration
            report.calibration_restored = _restore_calibration(jdir, jc.calibration_error,
                                                               fs.calibration)
        elif fs.calibration is None or not fs.trials and not _entries(jdir):
            if path.exists() and validate_session(path):
                invalid_aside = unique_aside(path, "damaged")
                rename_retrying(path, invalid_aside)
                report.damaged_kept_at = str(invalid_aside)
            report.action = "no-calibration"
            return report
        else:  # calibration.npz deleted: the file still has it
            jc.calibration = fs.calibration
    merged, from_entry = _merge(jdir, fs, report)
    report.n_trials = len(merged)
    report.problems_before = fs.problems
    events = jc.events if len(jc.events) >= len(fs.events) else fs.events
    n_file = len(fs.trials)
    if fs.valid and [_identity(t) for t in merged[:n_file]] == \
            [_identity(t) for t in fs.trials if t is not None] and \
            events[:len(fs.events)] == fs.events:
        # the file is good and a prefix of the merged session: append the rest
        missing = merged[n_file:]
        new_events = events[len(fs.events):]
        if missing or new_events:
            _check_space(path, jc)
            w = SessionWriter.open(path)
            w.deferred = True
            w.append_trials(missing, new_events) if missing else w.append_events(new_events)
            w.publish("appending the journal's trials")
            w.close()
        report.n_appended = len(missing)
        report.action = "appended" if missing or report.partial_recovered else "none"
    else:
        _check_space(path, jc)
        w = _build_from_journal(path, jc, merged, events)
        aside: Path | None = None
        if os.path.lexists(path):
            aside = unique_aside(path, "damaged")
            _keep_aside(path, aside)
        try:
            w.publish("rebuilding it from the journal and the file")
        except BaseException:
            if aside is not None and os.path.lexists(path):
                os.unlink(aside)
            elif aside is not None:
                os.rename(aside, path)
            raise
        w.close()
        fsync_dir(path.parent)
        report.damaged_kept_at = str(aside) if aside is not None else ""
        report.action = "rebuilt"
    _journal_as(jdir, merged, from_entry)
    if report.action != "none" or report.unreadable or report.deleted:
        log.warning("%s", report.summary())
    return report


def _keep_aside(path: Path, aside: Path) -> None:
    """Keep the file being replaced under ``aside``: a hard link (no copy, no space; the
    publish then replaces the name atomically), or where the volume has none (FAT,
    exFAT) a rename (the journal still holds everything if a kill comes in between)."""
    try:
        os.link(path, aside)
    except OSError:
        rename_retrying(path, aside)


def _identity(t: Trial) -> tuple:
    """What makes two copies the same trial: schedule index, status and the CRC of the
    samples (the same trial is never recorded twice with the same samples)."""
    idx = (t.extra_attrs or {}).get("schedule_index")
    return (None if idx is None else int(np.asarray(idx)), t.status, trial_digest(t))


def _merge(jdir: Path, fs: FileSalvage, report: RecoveryReport
           ) -> tuple[list[Trial], list[int | None]]:
    """The session's trials, position by position: the journal entry ``trial-000p`` if
    it reads, the file's ``t00p`` if it reads, both if they differ; a copy already taken
    (the same identity) is not taken again. Returns the trials and, for each, the journal
    entry number it came from (None: from the file)."""
    numbers = {_entry_number(p): p for p in _entries(jdir)}
    last = max(numbers, default=0)
    merged: list[Trial] = []
    origin: list[int | None] = []
    seen: set[tuple] = set()
    for pos in range(1, max(last, len(fs.trials)) + 1):
        entry = numbers.get(pos)
        jt = None
        why = "missing from the journal"
        if entry is not None:
            try:
                jt = load_trial_npz(entry)
            except JournalEntryError as exc:
                why = f"unreadable: {exc.problem.split('(', 1)[-1].rstrip(')')}"
        ft = fs.trials[pos - 1] if pos <= len(fs.trials) else None
        for t, src in ((jt, pos), (ft, None)):
            if t is not None and _identity(t) not in seen:
                seen.add(_identity(t))
                merged.append(t)
                origin.append(src)
        if jt is not None and ft is not None and _identity(jt) != _identity(ft):
            report.conflicts.append(f"trial-{pos:04d}.npz and the file's t{pos:03d} differ "
                                    "(both kept)")
        if jt is None and pos <= last:
            name = f"trial-{pos:04d}.npz"
            into = report.deleted if entry is None else report.unreadable
            what = why if entry is not None else "deleted"
            if ft is not None:
                into.append(f"{name} ({what}): kept from the file's t{pos:03d}")
            else:
                into.append(f"{name} ({what}): not in the file ("
                            + (fs.trial_problems.get(pos) or "it ends before") + "): lost")
                report.lost.append(name)
    return merged, origin


def _journal_as(jdir: Path, merged: list[Trial], origin: list[int | None]) -> None:
    """Make the journal's entries ``trial-0001 ...`` exactly the merged trials (after the
    file is published): damaged entries are kept aside as ``unreadable-trial-000p.npz.at-
    <time>``, entries the file supplied or that moved are written anew (durably).
    Interrupted, the next recovery merges to the same result."""
    numbers = {_entry_number(p): p for p in _entries(jdir)}
    for pos, (t, src) in enumerate(zip(merged, origin, strict=True), start=1):
        if src == pos:
            continue
        target = jdir / f"trial-{pos:04d}.npz"
        _aside_if_unreadable(jdir, numbers.get(pos))
        save_trial_npz(target, t)
    for pos, p in numbers.items():
        if pos > len(merged) and p.exists() and not _aside_if_unreadable(jdir, p):
            p.unlink()  # a readable entry past the end: its trial moved up
    fsync_dir(jdir)


def _aside_if_unreadable(jdir: Path, entry: Path | None) -> bool:
    if entry is None or not entry.exists():
        return False
    try:
        load_trial_meta(entry)
        load_trial_npz(entry)
        return False
    except JournalEntryError:
        rename_retrying(entry, unique_aside(jdir / f"unreadable-{entry.name}", "at"))
        return True


def _entries(jdir: Path) -> list[Path]:
    return sorted((p for p in jdir.iterdir() if _TRIAL_FILE.match(p.name)),
                  key=_entry_number)


def _entry_number(p: Path) -> int:
    m = _TRIAL_FILE.match(p.name)
    return int(m.group(1)) if m else 0


# -- the file's side, trial by trial --------------------------------------------------
@dataclass
class FileSalvage:
    """What a session file still holds, item by item (a damaged trial does not hide
    the others)."""

    valid: bool = False
    """The whole file validates and reads back (every checksum)."""
    problems: list[str] = field(default_factory=list)
    attrs: dict = field(default_factory=dict)
    calibration: Calibration | None = None
    events: list[Event] = field(default_factory=list)
    trials: list[Trial | None] = field(default_factory=list)
    trial_problems: dict[int, str] = field(default_factory=dict)


def salvage_file(path: Path) -> FileSalvage:
    """Read what ``path`` holds, trial by trial (each dataset's checksum verified)."""
    out = FileSalvage()
    s, out.problems = read_fully(path)
    if s is not None:
        out.valid = True
        out.calibration, out.events = s.calibration, s.events
        out.trials = list(s.trials)
        out.attrs = header_from_session_attrs(path) or {}
        return out
    try:
        f = _h5py().File(path, "r")
    except (OSError, ValueError):
        return out
    try:
        try:
            out.attrs = _root_header(f, path)
        except _DAMAGE_ERRORS:
            pass
        try:
            g = f["calibration"]
            out.calibration = Calibration(**{k: float(np.asarray(g.attrs[k]))
                                             for k in CALIBRATION_ATTRS},
                                          ramps={k: np.asarray(g[k][()]) for k in g})
        except _DAMAGE_ERRORS:
            out.calibration = None
        try:
            out.events = _read_events(f["events"])
        except _DAMAGE_ERRORS:
            out.events = []
        try:
            names = _trial_names(f["trials"])
        except _DAMAGE_ERRORS:
            names = []
        wanted = set(TRIAL_DATASETS) | set(OPTIONAL_SIGNALS)
        for i, name in enumerate(names, start=1):
            try:
                out.trials.append(_read_trial(f["trials"][name], name, wanted))
            except _DAMAGE_ERRORS as exc:
                out.trials.append(None)
                out.trial_problems[i] = f"damaged: {type(exc).__name__}"
    finally:
        f.close()
    return out


def _root_header(f, path: Path) -> dict:
    a = f.attrs
    known = {"format", "format_version", "participant", "created_utc", "software",
             "config_json", "seed", "backend"}
    extra = {k: (_as_str(a[k]) if isinstance(a[k], (str, bytes)) else a[k])
             for k in a if k not in known}
    seed = a.get("seed")
    header = {"participant": _as_str(a["participant"]),
              "created_utc": _as_str(a["created_utc"]),
              "software": _as_str(a.get("software", "")),
              "config_json": _as_str(a["config_json"]) if "config_json" in a else None,
              "seed": None if seed is None else int(np.asarray(seed)),
              "backend": _as_str(a["backend"]) if "backend" in a else None,
              "extra_attrs": extra, "file": path.name}
    return json.loads(json.dumps(header, default=json_default))


def header_from_session_attrs(path: Path) -> dict | None:
    """The journal header a session file's root attributes give (None if unreadable)."""
    try:
        with _h5py().File(path, "r") as f:
            return _root_header(f, path)
    except (*_DAMAGE_ERRORS, OSError):
        return None


def _header_readable(jdir: Path) -> bool:
    try:
        header = json.loads((jdir / "header.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(header, dict) and all(k in header for k in ("participant",
                                                                  "created_utc"))


def _journal_holds_data(jdir: Path) -> bool:
    try:
        return bool(_entries(jdir)) or (jdir / "calibration.npz").exists() or \
            (jdir / "partial.json").exists()
    except OSError:
        return False


def rebuild_header(path: Path, jdir: Path) -> str:
    """Write ``header.json`` anew from the session file's root attributes (the damaged
    one kept aside as ``header.json.damaged-<time>``); return what was done, in words.

    Raises
    ------
    SessionFileError
        If the session file cannot give the header back either (names both, and says
        what to do).
    """
    hp = jdir / "header.json"
    state = "missing" if not hp.exists() else "damaged"
    header = header_from_session_attrs(path) if path.exists() else None
    if not header or "schedule_json" not in (header.get("extra_attrs") or {}):
        raise SessionFileError(hp, f"is {state}, and the session file "
                               f"{'is missing' if not path.exists() else 'cannot give it back'}"
                               " (its root attributes hold the participant, configuration "
                               "and schedule): restore the file or header.json from a backup, "
                               f"then run `nmsid recover {path}`; the journal's trials are "
                               "left as they are")
    if hp.exists():
        rename_retrying(hp, unique_aside(hp, "damaged"))
    write_durable(hp, lambda fh: fh.write(json.dumps(header, indent=1).encode("utf-8")))
    return f"journal header.json was {state}: rebuilt from the session file's attributes"


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
    return {"participant": header["participant"], "created_utc": header["created_utc"],
            "software": header.get("software"), "config_json": header.get("config_json"),
            "seed": header.get("seed"), "backend": header.get("backend"),
            "extra_attrs": header.get("extra_attrs") or {}}


def _build_from_journal(path: Path, jc: JournalContents, trials: list[Trial],
                        events: list[Event] | None = None) -> SessionWriter:
    """A writer holding a complete session file built from the journal's header and
    calibration with ``trials`` (the merged ones) and ``events`` (default: the
    journal's), in memory (not yet published)."""
    try:
        image = SessionWriter.new_image(path, **_header_kwargs(jc.header))
    except (KeyError, TypeError) as exc:
        raise SessionFileError(journal_dir(path) / "header.json",
                               f"journal header lacks {exc}") from None
    if jc.calibration is None:  # the callers restore it first: a session needs one
        raise SessionFileError(journal_dir(path), "the journal holds no calibration to "
                               "rebuild the session file from")
    w = SessionWriter(path, image=image)
    w.deferred = True
    w.write_calibration(jc.calibration)
    w.append_trials(trials, jc.events if events is None else events)
    return w


def clean_leftovers_if_idle(path: str | os.PathLike) -> list[str]:
    """Remove the leftovers of :func:`remove_leftovers` if nobody writes the session now
    (the lock is taken for the moment; a live session is left alone). For commands that
    only read a session (``nmsid validate``). Returns what was removed (names)."""
    before = session_state(path, count_file_trials=False).leftovers
    if not before:
        return []
    try:
        lock = SessionLock.acquire(path, "nmsid validate")
    except (SessionLockedError, OSError):
        return []
    try:
        remove_leftovers(path)
    finally:
        lock.release()
    after = set(session_state(path, count_file_trials=False).leftovers)
    return [n for n in before if n not in after]


def check_stored_header(path: str | os.PathLike) -> None:
    """Before ``run --resume`` reads the stored configuration: a journal ``header.json``
    that exists but cannot be read is rebuilt from the session file (under the session's
    lock), or refused in one line saying what to do (never a JSONDecodeError).

    Raises
    ------
    SessionFileError
        If the header is damaged and the file cannot give it back (see
        :func:`rebuild_header`); SessionLockedError if another process writes the session.
    """
    path = Path(path)
    jdir = journal_dir(path)
    if not (jdir / "header.json").exists() or _header_readable(jdir):
        return
    lock = SessionLock.acquire(path, "nmsid run --resume")
    try:
        if not _header_readable(jdir):
            rebuild_header(path, jdir)
    finally:
        lock.release()
