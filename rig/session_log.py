"""Crash-safe session logging: a write-ahead journal beside the HDF5 session file.

HDF5 can be left unreadable if the process dies in the middle of a write, so every item is
first made durable in a journal directory ``<file>.journal/`` and only then appended to
the HDF5 file (through :mod:`rig.session_file`, which this module does not change):

``header.json``
    participant, created_utc, software, config_json, seed, backend, schedule_json
    (written once, tmp + fsync + rename).
``calibration.npz``
    the four currents, Fmin/Fmax and the ramps (tmp + fsync + rename). The HDF5 file is
    created when the calibration is known, so a file on disk always has one.
``events.jsonl``
    one JSON object per event (utc, kind, detail), appended and flushed as it happens.
``trial-0001.npz``, ``trial-0002.npz``, ...
    each completed or aborted trial, in the order of ``/trials/t001``, ``t002``, ...:
    written to a temporary file, fsynced and renamed BEFORE it is appended to the HDF5.
``partial.json`` + ``partial.f64``
    the trial in progress: its metadata, and its samples streamed chunk by chunk as rows of
    float64 (one ``write`` per chunk, so a killed process leaves whole rows behind, at most
    a torn last row which is ignored).

:func:`recover` rebuilds a damaged or incomplete HDF5 file from the journal (the damaged
file is kept aside, a good file is never overwritten) and turns the partial trial into an
aborted trial ("process ended during trial"). The journal is removed only after a clean
finish.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import logging
import os
import re
import shutil
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig.session_file import (Calibration, Event, SessionExistsError, SessionFileError,
                              SessionWriter, Trial, read_session, software_id, utc_now,
                              validate_session)

log = logging.getLogger(__name__)

PARTIAL_ABORT_REASON = "process ended during trial"
_TRIAL_FILE = re.compile(r"^trial-(\d{4,})\.npz$")
_TRIAL_META_FIELDS = [f.name for f in dataclasses.fields(Trial)
                      if f.name not in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench",
                                        "sync")]
_CAL_FIELDS = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")
PARTIAL_COLUMNS = ("force_N", "rE", "I_ext_mA", "I_flex_mA")


def utc_now_ms() -> str:
    """The current time as ISO 8601 UTC with milliseconds (event time stamps)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def journal_dir(path: str | os.PathLike) -> Path:
    """The journal directory of a session file: ``<file>.journal``."""
    p = Path(path)
    return p.with_name(p.name + ".journal")


# -- durable small writes ----------------------------------------------------------------
def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_durable(target: Path, write) -> None:
    """Write via ``write(fileobj)`` to a temp file, fsync, rename onto ``target``."""
    tmp = target.with_name(target.name + ".tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, target)
    _fsync_dir(target.parent)


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, bytes):
        return obj.decode("utf-8", "replace")
    raise TypeError(f"not JSON-able: {type(obj).__name__}")


def trial_meta(trial: Trial) -> dict[str, Any]:
    """A trial's attributes as a JSON-able dict (no sample arrays)."""
    return json.loads(json.dumps({k: getattr(trial, k) for k in _TRIAL_META_FIELDS},
                                 default=_json_default))


def _save_trial_npz(target: Path, trial: Trial) -> None:
    arrays = {k: np.asarray(getattr(trial, k), dtype=np.float64)
              for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N")}
    if trial.wrench is not None:
        arrays["wrench"] = np.asarray(trial.wrench, dtype=np.float64)
    if trial.sync is not None:
        arrays["sync"] = np.asarray(trial.sync, dtype=np.float64)
    meta = np.array(json.dumps(trial_meta(trial)))
    _write_durable(target, lambda fh: np.savez(fh, __meta__=meta, **arrays))


def load_trial_npz(path: Path) -> Trial:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["__meta__"]))
        arrays = {k: np.array(z[k]) for k in z.files if k != "__meta__"}
    kw = {k: v for k, v in meta.items() if k in _TRIAL_META_FIELDS}
    return Trial(**kw, **{k: arrays.get(k) for k in ("rE", "I_ext_mA", "I_flex_mA",
                                                       "force_N", "wrench", "sync")})


def _save_calibration(target: Path, cal: Calibration) -> None:
    meta = np.array(json.dumps({k: float(getattr(cal, k)) for k in _CAL_FIELDS}))
    ramps = {f"ramp__{k}": np.asarray(v, dtype=float) for k, v in cal.ramps.items()}
    _write_durable(target, lambda fh: np.savez(fh, __meta__=meta, **ramps))


def _load_calibration(path: Path) -> Calibration:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["__meta__"]))
        ramps = {k[len("ramp__"):]: np.array(z[k]) for k in z.files if k.startswith("ramp__")}
    return Calibration(**meta, ramps=ramps)


# -- the journal ---------------------------------------------------------------------
@dataclass
class JournalContents:
    """What a journal directory holds."""

    header: dict[str, Any]
    calibration: Calibration | None
    events: list[Event]
    trial_files: list[Path]
    partial_meta: dict[str, Any] | None = None
    partial_path: Path | None = None

    def trial_metas(self) -> list[dict[str, Any]]:
        out = []
        for p in self.trial_files:
            with np.load(p, allow_pickle=False) as z:
                out.append(json.loads(str(z["__meta__"])))
        return out


def read_journal(jdir: Path) -> JournalContents:
    """Read a journal directory (tolerating a torn last event line).

    Raises
    ------
    SessionFileError
        If the header is missing or unreadable.
    """
    header_path = jdir / "header.json"
    try:
        header = json.loads(header_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise SessionFileError(jdir, f"journal header unreadable ({exc})") from None
    cal = None
    if (jdir / "calibration.npz").exists():
        cal = _load_calibration(jdir / "calibration.npz")
    events = []
    ev_path = jdir / "events.jsonl"
    if ev_path.exists():
        for line in ev_path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                d = json.loads(line)
                events.append(Event(d["utc"], d["kind"], d.get("detail", "")))
            except (json.JSONDecodeError, KeyError, TypeError):
                continue  # a line torn by a kill
    files = sorted((p for p in jdir.iterdir() if _TRIAL_FILE.match(p.name)),
                   key=lambda p: int(_TRIAL_FILE.match(p.name).group(1)))
    for i, p in enumerate(files):
        if int(_TRIAL_FILE.match(p.name).group(1)) != i + 1:
            raise SessionFileError(jdir, f"journal trial files are not numbered 1, 2, ... "
                                         f"(found {p.name} at position {i + 1})")
    pmeta = None
    if (jdir / "partial.json").exists():
        try:
            pmeta = json.loads((jdir / "partial.json").read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            pmeta = None
    return JournalContents(header, cal, events, files, pmeta,
                           jdir / "partial.f64" if pmeta is not None else None)


def _partial_trial(jc: JournalContents) -> Trial:
    meta = dict(jc.partial_meta)
    columns = meta.pop("columns")
    meta.pop("seq", None)
    n_cols = len(columns)
    raw = b""
    if jc.partial_path is not None and jc.partial_path.exists():
        raw = jc.partial_path.read_bytes()
    row = 8 * n_cols
    n = len(raw) // row
    data = np.frombuffer(raw[: n * row], dtype=np.float64).reshape(n, n_cols)
    cols = {c: data[:, i].copy() for i, c in enumerate(columns)}
    wrench = None
    if all(f"wrench{k}" in cols for k in range(6)):
        wrench = np.column_stack([cols[f"wrench{k}"] for k in range(6)])
    kw = {k: v for k, v in meta.items() if k in _TRIAL_META_FIELDS}
    kw["status"] = "aborted"
    kw["abort_reason"] = PARTIAL_ABORT_REASON
    return Trial(**kw, rE=cols["rE"], I_ext_mA=cols["I_ext_mA"], I_flex_mA=cols["I_flex_mA"],
                 force_N=cols["force_N"], wrench=wrench, sync=cols.get("sync"))


# -- recovery --------------------------------------------------------------------------
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


def _digest(trial: Trial) -> int:
    """CRC-32 of a trial's four sample arrays (as float64)."""
    crc = 0
    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N"):
        crc = zlib.crc32(np.ascontiguousarray(getattr(trial, k), dtype=np.float64).tobytes(),
                         crc)
    return crc


def _read_fully(path: Path):
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


def _unique_aside(path: Path, tag: str) -> Path:
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
        s, problems = _read_fully(path)
        if s is not None:
            return RecoveryReport(str(path), "none", n_trials=len(s.trials))
        raise SessionFileError(path, f"{problems[0]}; and there is no journal "
                                     f"({jdir.name}) to recover it from")
    if not (jdir / "header.json").exists():  # nothing was ever journaled in it
        s, _ = _read_fully(path)
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
            trial = _partial_trial(jc)
            _save_trial_npz(target, trial)
            report.partial_recovered = True
            report.partial_samples = trial.n_samples
            _append_event_line(jdir, Event(utc_now(), "recovered",
                                           f"trial {seq} (schedule index "
                                           f"{trial.extra_attrs.get('schedule_index', '?')}) "
                                           f"kept as aborted: {PARTIAL_ABORT_REASON}, "
                                           f"{trial.n_samples} samples"))
        for name in ("partial.json", "partial.f64"):
            (jdir / name).unlink(missing_ok=True)
        jc = read_journal(jdir)
    if jc.calibration is None:
        if path.exists() and validate_session(path):
            aside = _unique_aside(path, "damaged")
            os.replace(path, aside)
            report.damaged_kept_at = str(aside)
        report.action = "no-calibration"
        return report
    metas = jc.trial_metas()
    report.n_trials = len(metas)
    s, problems = _read_fully(path)
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
        aside = _unique_aside(path, "damaged")
        os.replace(path, aside)
        report.damaged_kept_at = str(aside)
    os.replace(tmp, path)
    _fsync_dir(path.parent)
    report.action = "rebuilt"
    log.warning("%s", report.summary())
    return report


def _create_from_header(path: Path, header: dict) -> SessionWriter:
    return SessionWriter.create(
        path, participant=header["participant"], created_utc=header["created_utc"],
        software=header.get("software"), config_json=header.get("config_json"),
        seed=header.get("seed"), backend=header.get("backend"),
        extra_attrs=header.get("extra_attrs") or {})


def _build_from_journal(path: Path, jc: JournalContents) -> None:
    w = _create_from_header(path, jc.header)
    w.write_calibration(jc.calibration)
    for p in jc.trial_files:
        w.append_trial(load_trial_npz(p))
    w.append_events(jc.events)
    with open(path, "rb+") as fh:
        os.fsync(fh.fileno())


def _append_event_line(jdir: Path, ev: Event) -> None:
    with open(jdir / "events.jsonl", "a", encoding="utf-8") as fh:
        fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind, "detail": ev.detail}) + "\n")
        fh.flush()


# -- the logger the engine uses ----------------------------------------------------------
class SessionLog:
    """Write one session: journal first, then the HDF5 file.

    Use :meth:`create` for a new session and :meth:`resume` to continue one.
    """

    def __init__(self, path: Path, header: dict, *, calibration: Calibration | None = None,
                 events: list[Event] | None = None, trials: list[dict] | None = None):
        self.path = Path(path)
        self.jdir = journal_dir(self.path)
        self.header = header
        self.calibration = calibration
        self.events: list[Event] = list(events or [])
        self._events_in_h5 = len(self.events) if calibration is not None else 0
        self.trials: list[dict] = list(trials or [])
        self._digests: list[int] = []
        """CRC of the samples of each trial written by this process."""
        """Metadata of every trial written (journal order = file order)."""
        self._writer: SessionWriter | None = (SessionWriter(self.path)
                                              if calibration is not None else None)
        self._ev_fh = open(self.jdir / "events.jsonl", "a", encoding="utf-8")
        self._partial_fd: int | None = None
        self._partial_cols: tuple[str, ...] = ()

    # -- opening -------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | os.PathLike, *, participant: str, config_json: str,
               seed: int | None, backend: str, schedule_json: str,
               created_utc: str | None = None, extra_attrs: dict | None = None
               ) -> SessionLog:
        """Start a new session at ``path`` (refused if the file or its journal exists)."""
        path = Path(path)
        jdir = journal_dir(path)
        if path.exists():
            raise SessionExistsError(path)
        if jdir.exists():
            raise SessionExistsError(jdir)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {"participant": participant, "created_utc": created_utc or utc_now(),
                  "software": software_id(), "config_json": config_json,
                  "seed": None if seed is None else int(seed), "backend": backend,
                  "extra_attrs": {**(extra_attrs or {}), "schedule_json": schedule_json},
                  "file": path.name}
        # the journal appears complete with its header or not at all: build it aside
        tmp = jdir.with_name(f"{jdir.name}.tmp-{os.getpid()}")
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir()
        _write_durable(tmp / "header.json",
                       lambda fh: fh.write(json.dumps(header, indent=1).encode("utf-8")))
        if jdir.exists():
            shutil.rmtree(tmp)
            raise SessionExistsError(jdir)
        os.rename(tmp, jdir)
        _fsync_dir(jdir.parent)
        return cls(path, header)

    @classmethod
    def resume(cls, path: str | os.PathLike) -> tuple[SessionLog, RecoveryReport | None]:
        """Continue a session: recover first if its journal shows it did not end cleanly.

        Returns
        -------
        (SessionLog, RecoveryReport or None)
        """
        path = Path(path)
        jdir = journal_dir(path)
        report = None
        if jdir.is_dir() and not (jdir / "header.json").exists():
            os.rename(jdir, _unique_aside(jdir, "headerless"))  # keep it, but aside
        if jdir.is_dir():
            report = recover(path)
        elif path.exists():
            _journal_from_file(path, jdir)
        else:
            raise SessionFileError(path, "no such file and no journal to resume from")
        jc = read_journal(jdir)
        return cls(path, jc.header, calibration=jc.calibration, events=jc.events,
                   trials=jc.trial_metas()), report

    # -- writing ---------------------------------------------------------------------
    def event(self, kind: str, detail: str = "", utc: str | None = None) -> Event:
        """Record an event: journal now; HDF5 with the next trial / calibration / flush."""
        ev = Event(utc or utc_now_ms(), str(kind), str(detail))
        self.events.append(ev)
        self._ev_fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind,
                                      "detail": ev.detail}) + "\n")
        self._ev_fh.flush()
        return ev

    def flush_events(self) -> None:
        """Copy the events not yet in the HDF5 file to it (once the file exists)."""
        if self._writer is None or self._events_in_h5 >= len(self.events):
            return
        self._writer.append_events(self.events[self._events_in_h5:])
        self._events_in_h5 = len(self.events)

    def write_calibration(self, cal: Calibration) -> None:
        """Journal the calibration, then create the HDF5 file with it."""
        if self.calibration is not None:
            raise RuntimeError(f"{self.path}: calibration already written")
        problems = cal.problems()
        if problems:
            raise ValueError(f"{self.path}: refusing calibration: " + "; ".join(problems))
        _save_calibration(self.jdir / "calibration.npz", cal)
        self.calibration = cal
        self._writer = _create_from_header(self.path, self.header)
        self._writer.write_calibration(cal)
        self.flush_events()

    def begin_trial(self, meta: Trial, columns: tuple[str, ...] = PARTIAL_COLUMNS) -> None:
        """Start streaming the trial in progress to ``partial.f64``."""
        self._close_partial()
        pmeta = trial_meta(meta)
        pmeta["columns"] = list(columns)
        pmeta["seq"] = len(self.trials) + 1
        # empty the stream BEFORE the new metadata names it: a kill in between leaves the
        # previous trial's metadata (already journaled, so ignored) over an empty stream
        self._partial_cols = tuple(columns)
        self._partial_fd = os.open(self.jdir / "partial.f64",
                                   os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
        tmp = self.jdir / "partial.json.tmp"
        tmp.write_text(json.dumps(pmeta), encoding="utf-8")
        os.replace(tmp, self.jdir / "partial.json")  # atomic; no fsync: a kill keeps it

    def append_chunk(self, **columns: np.ndarray) -> None:
        """Append samples of the trial in progress (one write, whole rows)."""
        if self._partial_fd is None:
            return
        first = columns[self._partial_cols[0]]
        rows = np.empty((len(first), len(self._partial_cols)), dtype=np.float64)
        for j, c in enumerate(self._partial_cols):
            rows[:, j] = columns[c]
        os.write(self._partial_fd, rows.data)

    def _close_partial(self) -> None:
        if self._partial_fd is not None:
            os.close(self._partial_fd)
            self._partial_fd = None

    def end_trial(self, trial: Trial) -> str:
        """Make the trial durable in the journal, then append it to the HDF5 file.

        Returns the trial's name in the file (``t001``, ...).
        """
        if self._writer is None:
            raise RuntimeError(f"{self.path}: no calibration yet; cannot write a trial")
        self._close_partial()
        seq = len(self.trials) + 1
        trial.name = f"t{seq:03d}"
        _save_trial_npz(self.jdir / f"trial-{seq:04d}.npz", trial)
        # partial.json / partial.f64 stay: their seq now names a journaled trial, which
        # recovery ignores; the next begin_trial reuses them
        self.trials.append(trial_meta(trial))
        self._digests.append(_digest(trial))
        name = self._writer.append_trial(trial)
        self.flush_events()
        return name

    def discard_partial(self) -> None:
        """Drop the in-progress stream (a trial that never started output)."""
        self._close_partial()
        for name in ("partial.json", "partial.f64"):
            (self.jdir / name).unlink(missing_ok=True)

    def set_root_attrs(self, **attrs) -> None:
        if self._writer is not None:
            self._writer.set_root_attrs(**attrs)

    def finish(self) -> bool:
        """After a clean end: put every event in the file, check it, remove the journal.

        Returns True if the journal was removed (the file validated and holds every
        journaled trial); otherwise the journal is kept for ``nmsid recover``.
        """
        self.flush_events()
        self.close()
        if self._writer is None:
            return False
        s, problems = _read_fully(self.path)
        if s is None:
            log.error("%s: not removing the journal, the file has problems: %s", self.path,
                      problems[0])
            return False
        files = read_journal(self.jdir).trial_files
        digests = list(self._digests)
        if len(digests) < len(files):  # trials journaled before this process (resume)
            digests = [_digest(load_trial_npz(p)) for p in files[:len(files) - len(digests)]] \
                + digests
        if len(s.trials) != len(files) or [_digest(t) for t in s.trials] != digests:
            log.error("%s: file and journal differ (%d / %d trials); journal kept", self.path,
                      len(s.trials), len(files))
            return False
        # rename first (atomic), then delete: a kill never leaves half a journal behind
        gone = self.jdir.with_name(f"{self.jdir.name}.done-{os.getpid()}")
        os.rename(self.jdir, gone)
        shutil.rmtree(gone, ignore_errors=True)
        return True

    def close(self) -> None:
        self._close_partial()
        if not self._ev_fh.closed:
            try:
                self._ev_fh.flush()
                os.fsync(self._ev_fh.fileno())
            except OSError:
                pass
            self._ev_fh.close()


def _journal_from_file(path: Path, jdir: Path) -> None:
    """Rebuild a journal from a good session file (resuming a cleanly ended session)."""
    problems = validate_session(path)
    if problems:
        raise SessionFileError(path, problems[0] + "; and there is no journal to recover "
                                                   "from")
    s = read_session(path)
    final, jdir = jdir, jdir.with_name(f"{jdir.name}.tmp-{os.getpid()}")
    if jdir.exists():
        shutil.rmtree(jdir)
    jdir.mkdir()  # built aside, renamed when complete: a kill leaves no half journal
    extra = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in s.attrs.items()}
    extra = json.loads(json.dumps(extra, default=_json_default))
    header = {"participant": s.participant, "created_utc": s.created_utc,
              "software": s.software, "config_json": s.config_json, "seed": s.seed,
              "backend": s.backend, "extra_attrs": extra, "file": path.name}
    _write_durable(jdir / "header.json",
                   lambda fh: fh.write(json.dumps(header, indent=1,
                                                  default=_json_default).encode("utf-8")))
    _save_calibration(jdir / "calibration.npz", s.calibration)
    for i, t in enumerate(s.trials):
        _save_trial_npz(jdir / f"trial-{i + 1:04d}.npz", t)
    with open(jdir / "events.jsonl", "w", encoding="utf-8") as fh:
        for ev in s.events:
            fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind, "detail": ev.detail}) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.rename(jdir, final)
    _fsync_dir(final.parent)
