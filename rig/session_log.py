"""Crash-safe session logging: a write-ahead journal beside the HDF5 session file.

HDF5 can be left unreadable if the process dies in the middle of a write, so every item is
first made durable in a journal directory ``<file>.journal/`` and only then appended to
the HDF5 file (through :mod:`nmsid.protocols.session_file`, which this module does not change):

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

import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np

from nmsid.protocols.errors import CalibrationError, DiskFullError, SessionLockedError
from nmsid.protocols.session_file import (
    Calibration,
    Event,
    SessionExistsError,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    software_id,
    utc_now,
    validate_session,
)
from nmsid.protocols.session_lock import SessionLock, live_writer
from nmsid.protocols.session_model import PARTICIPANT_PATTERN, TRIAL_NAME_PATTERN, _h5py
from nmsid.protocols.session_publish import (
    SPACE_MARGIN_BYTES,
    FileHeldError,
    free_bytes,
    o_binary,
    publish_image,
    rename_retrying,
    replace_retrying,
)
from nmsid.protocols.session_writer import check_seed, counts_memo

# re-exported names (callers import them from here)
from nmsid.rig.journal import (  # noqa: F401
    DIGEST_SIGNALS,
    PARTIAL_ABORT_REASON,
    PARTIAL_COLUMNS,
    JournalContents,
    arrays_digest,
    disk_error,
    fsync_dir,
    journal_dir,
    json_default,
    load_trial_npz,
    read_journal,
    save_calibration,
    save_trial_npz,
    trial_digest,
    trial_meta,
    utc_now_ms,
    write_durable,
)
from nmsid.rig.recovery import (  # noqa: F401
    RecoveryReport,
    _header_kwargs,
    create_from_header,
    read_fully,  # noqa: F401
    recover,
    remove_leftovers,
    unique_aside,
)
from nmsid.rig.session_clock import SessionClock

log = logging.getLogger(__name__)


class SessionLog:
    """Write one session: journal first, then the HDF5 file.

    Use :meth:`create` for a new session and :meth:`resume` to continue one.
    """

    def __init__(self, path: Path, header: dict, *, calibration: Calibration | None = None,
                 events: list[Event] | None = None, trials: list[dict] | None = None,
                 lock: SessionLock | None = None):
        self.path = Path(path)
        self.lock = lock
        """The session's writer lock (held until :meth:`close` / :meth:`finish`)."""
        self.jdir = journal_dir(self.path)
        self.header = header
        self.calibration = calibration
        self.events: list[Event] = list(events or [])
        self._events_in_h5 = len(self.events) if calibration is not None else 0
        self.trials: list[dict] = list(trials or [])
        self._digests: list[int] = []
        """CRC of the samples of each trial written by this process."""
        """Metadata of every trial written (journal order = file order)."""
        self._writer: SessionWriter | None = None
        if calibration is not None:
            self._writer = SessionWriter(self.path)
            self._writer.deferred = True  # trials go to the journal; the file at the end
        self._ev_fh = open(self.jdir / "events.jsonl", "a", encoding="utf-8")
        self._partial_fd: int | None = None
        self._partial_cols: tuple[str, ...] = ()
        self._partial_meta: dict = {}
        self._partial_rows = 0
        self.clock = SessionClock()
        """Trial and event times: monotonic offsets from the UTC time read now (a step of
        the computer's clock is recorded as a ``clock_step`` event, not followed)."""
        self._started_utc: str | None = None

    # -- opening -------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | os.PathLike, *, participant: str, config_json: str,
               seed: int | None, backend: str, schedule_json: str,
               created_utc: str | None = None, extra_attrs: dict | None = None
               ) -> SessionLog:
        """Start a new session at ``path`` (refused if the file or its journal exists, or
        another process writes it)."""
        path = Path(path)
        check_seed(path, seed)  # the file stores it as int64: refuse now, not after calibration
        if not PARTICIPANT_PATTERN.match(participant or ""):
            raise SessionFileError(path, f"participant code {participant!r} is not valid: "
                                         "use 1 to 64 letters, digits, '_' or '-'")
        check_new_session_path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = SessionLock.acquire(path, "nmsid run")
        try:
            check_new_session_path(path)
            remove_leftovers(path)
            return cls._create_locked(path, lock, participant=participant,
                                      config_json=config_json, seed=seed, backend=backend,
                                      schedule_json=schedule_json, created_utc=created_utc,
                                      extra_attrs=extra_attrs)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def _create_locked(cls, path: Path, lock: SessionLock, *, participant, config_json, seed,
                       backend, schedule_json, created_utc, extra_attrs) -> SessionLog:
        jdir = journal_dir(path)
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
        write_durable(tmp / "header.json",
                       lambda fh: fh.write(json.dumps(header, indent=1).encode("utf-8")))
        if jdir.exists():
            shutil.rmtree(tmp)
            raise SessionExistsError(jdir)
        rename_retrying(tmp, jdir)
        fsync_dir(jdir.parent)
        return cls(path, header, lock=lock)

    @classmethod
    def resume(cls, path: str | os.PathLike) -> tuple[SessionLog, RecoveryReport | None]:
        """Continue a session: recover first if its journal shows it did not end cleanly.

        Returns
        -------
        (SessionLog, RecoveryReport or None)
        """
        path = Path(path)
        jdir = journal_dir(path)
        lock = SessionLock.acquire(path, "nmsid run --resume")
        try:
            report = None
            remove_leftovers(path)
            if jdir.is_dir():  # a missing or damaged header is rebuilt from the file
                report = recover(path)
            if not jdir.is_dir():
                if not path.exists():
                    raise SessionFileError(path, "no such file and no journal to resume "
                                                 "from")
                _journal_from_file(path, jdir)
            jc = read_journal(jdir)
            if jc.calibration is None and jc.calibration_error:
                raise SessionFileError(jdir, jc.calibration_error)
            return cls(path, jc.header, calibration=jc.calibration, events=jc.events,
                       trials=jc.trial_metas(), lock=lock), report
        except BaseException:
            lock.release()
            raise

    # -- writing ---------------------------------------------------------------------
    def utc(self) -> str:
        """The session's time now (see :attr:`clock`), after recording a step of the
        computer's clock if there was one."""
        self._note_clock_step()
        return self.clock.utc()

    def _note_clock_step(self) -> None:
        detail = self.clock.step()
        if detail:
            self._record(Event(self.clock.utc(), "clock_step", detail))

    def event(self, kind: str, detail: str = "", utc: str | None = None) -> Event:
        """Record an event: journal now; HDF5 with the next trial / calibration / flush.
        ``utc`` defaults to the session's monotonic time (:meth:`utc`)."""
        ev = Event(utc or self.utc(), str(kind), str(detail))
        return self._record(ev)

    def _record(self, ev: Event) -> Event:
        self.events.append(ev)
        try:
            self._ev_fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind,
                                          "detail": ev.detail}) + "\n")
            self._ev_fh.flush()
        except OSError as exc:  # a full disk: the event stays in memory (and the log)
            log.warning("%s: event %s not journaled (%s)", self.path, ev.kind,
                        exc.strerror or exc)
        return ev

    def flush_events(self) -> None:
        """Copy the events not yet in the in-memory file to it (once the file exists);
        :meth:`publish` writes them to disk."""
        if self._writer is None or self._events_in_h5 >= len(self.events):
            return
        self._writer.append_events(self.events[self._events_in_h5:])
        self._events_in_h5 = len(self.events)

    def publish(self, *, delays_s: tuple[float, ...] | None = None) -> bool:
        """Publish the in-memory file (every trial and event so far) as a new version.

        Returns
        -------
        bool
            True if published. False if the disk is full or (Windows) another program
            holds the file open: the reason is logged, naming the file, and nothing is
            lost (the journal holds every trial; ``nmsid recover`` publishes it).
        """
        if self._writer is None:
            return False
        self.flush_events()
        try:
            self._writer.publish("publishing the session", delays_s=delays_s)
        except SessionFileError as exc:  # DiskFullError, FileHeldError, SessionWriteError
            log.error("%s", exc)
            return False
        return True

    def _pending_events(self) -> list[Event]:
        return self.events[self._events_in_h5:]

    def write_calibration(self, cal: Calibration) -> None:
        """Journal the calibration, then create the HDF5 file with it."""
        if self.calibration is not None:
            raise RuntimeError(f"{self.path}: calibration already written")
        problems = cal.problems()
        if problems:
            raise CalibrationError(f"{self.path}: refusing calibration: " + "; ".join(problems))
        save_calibration(self.jdir / "calibration.npz", cal)
        self.calibration = cal
        w = SessionWriter(self.path, image=SessionWriter.new_image(
            self.path, **_header_kwargs(self.header)))
        w.deferred = True
        pending = self._pending_events()
        w.write_calibration(cal, events=pending)
        # the file appears once, complete with its calibration, and never over another
        publish_image(self.path, w.image(), exclusive=True,
                      doing="creating the session file")
        w.unpublished = False
        self._writer = w
        self._events_in_h5 += len(pending)

    def begin_trial(self, meta: Trial, columns: tuple[str, ...] = PARTIAL_COLUMNS) -> None:
        """Start streaming the trial in progress to ``partial.f64``."""
        self._close_partial()
        # the trial starts now on the session's clock (monotonic offset; not the wall
        # clock, which may step): end_trial gives the stored trial this time
        self._started_utc = self.utc()
        meta.started_utc = self._started_utc
        pmeta = trial_meta(meta)
        pmeta["columns"] = list(columns)
        pmeta["seq"] = len(self.trials) + 1
        # empty the stream BEFORE the new metadata names it: a kill in between leaves the
        # previous trial's metadata (already journaled, so ignored) over an empty stream
        self._partial_cols = tuple(columns)
        self._partial_fd = os.open(self.jdir / "partial.f64",  # O_BINARY: see session_publish
                                   os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND
                                   | o_binary(), 0o644)
        self._partial_meta = pmeta
        self._partial_rows = 0
        self._write_partial_meta()

    def _write_partial_meta(self) -> None:
        tmp = self.jdir / "partial.json.tmp"
        try:
            tmp.write_text(json.dumps(self._partial_meta), encoding="utf-8")
            # atomic; no fsync: a kill keeps it; retried while Windows' scanners hold it
            replace_retrying(tmp, self.jdir / "partial.json")
        except FileHeldError:
            tmp.unlink(missing_ok=True)
            raise
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise disk_error(self.jdir / "partial.json", exc) from None

    def append_chunk(self, *, wrench: np.ndarray | None = None,
                     sync: np.ndarray | None = None, **columns: np.ndarray) -> None:
        """Append samples of the trial in progress (one write, whole rows).

        ``wrench`` (n x 6) and ``sync`` (n), when the acquisition records them, are
        streamed too (from the first chunk on), so a trial kept by ``recover`` carries
        them as the contract lists them.
        """
        if self._partial_fd is None:
            return
        if wrench is not None:
            w = np.asarray(wrench, dtype=np.float64).reshape(-1, 6)
            columns.update({f"wrench{k}": w[:, k] for k in range(6)})
        if sync is not None:
            columns["sync"] = np.asarray(sync, dtype=np.float64).reshape(-1)
        if self._partial_rows == 0 and set(columns) - set(self._partial_cols):
            # the first chunk says which signals this rig records: name them before the
            # first row is written (the stream is still empty)
            self._partial_cols = tuple(self._partial_cols) + tuple(
                sorted(set(columns) - set(self._partial_cols)))
            self._partial_meta["columns"] = list(self._partial_cols)
            self._write_partial_meta()
        first = columns[self._partial_cols[0]]
        rows = np.full((len(first), len(self._partial_cols)), np.nan, dtype=np.float64)
        for j, c in enumerate(self._partial_cols):
            if c in columns:
                rows[:, j] = columns[c]
        try:
            os.write(self._partial_fd, rows.data)
        except OSError as exc:
            raise disk_error(self.jdir / "partial.f64", exc, rows.nbytes,
                             "streaming the trial in progress") from None
        self._partial_rows += len(rows)

    def _close_partial(self) -> None:
        if self._partial_fd is not None:
            os.close(self._partial_fd)
            self._partial_fd = None

    @property
    def next_trial_name(self) -> str:
        """The name the next trial gets in the file (``t001``, ...): how the engine's
        events name it from its start on."""
        return f"t{len(self.trials) + 1:03d}"

    def end_trial(self, trial: Trial) -> str:
        """Make the trial durable in the journal, then append it to the in-memory file
        (published at the end of the session: a trial end costs the same at the first
        trial as at the last, and a reader holding the file never stops the session).

        Returns the trial's name in the file (``t001``, ...).
        """
        if self._writer is None:
            raise RuntimeError(f"{self.path}: no calibration yet; cannot write a trial")
        self._close_partial()
        self._note_clock_step()
        if self._started_utc is not None:
            trial.started_utc = self._started_utc
            self._started_utc = None
        seq = len(self.trials) + 1
        trial.name = self.next_trial_name
        with counts_memo():  # the journal and the file find the A/D grid once
            save_trial_npz(self.jdir / f"trial-{seq:04d}.npz", trial)
            # partial.json / partial.f64 stay: their seq now names a journaled trial,
            # which recovery ignores; the next begin_trial reuses them
            self.trials.append(trial_meta(trial))
            self._digests.append(trial_digest(trial))
            pending = self._pending_events()
            name = self._writer.append_trial(trial, events=pending)
        self._events_in_h5 += len(pending)
        return name

    def set_root_attrs(self, **attrs) -> None:
        if self._writer is not None:
            self._writer.set_root_attrs(**attrs)

    def finish(self) -> bool:
        """After a clean end: publish the file with every trial and event, check it,
        remove the journal.

        Returns True if the journal was removed (the file validated and holds every
        journaled trial); otherwise the journal is kept for ``nmsid recover`` (a full disk,
        or on Windows another program holding the file: both are logged, naming it).
        """
        try:
            return self._finish()
        finally:
            self.release()

    def _finish(self) -> bool:
        if self._writer is None:
            self.close(release=False)
            return False
        published = self.publish()
        self.close(release=False, publish=False)
        if not published:
            log.error("%s: the journal %s is kept: it holds every trial; run `nmsid recover "
                      "%s` once the file can be written", self.path, self.jdir.name,
                      self.path)
            return False
        # the file validates (every dataset read, its checksum verified, its values
        # checked) and holds, bit for bit, every trial the journal holds
        problems = validate_session(self.path)
        if not problems:
            try:
                in_file = file_trial_digests(self.path)
            except Exception as exc:  # h5py raises KeyError / OSError / RuntimeError
                problems = [f"data unreadable ({type(exc).__name__}: {exc})"]
        if problems:
            log.error("%s: not removing the journal, the file has problems: %s", self.path,
                      problems[0])
            return False
        files = read_journal(self.jdir).trial_files
        digests = list(self._digests)
        if len(digests) < len(files):  # trials journaled before this process (resume)
            digests = [trial_digest(load_trial_npz(p))
                       for p in files[:len(files) - len(digests)]] \
                + digests
        if len(in_file) != len(files) or in_file != digests:
            log.error("%s: file and journal differ (%d / %d trials); journal kept", self.path,
                      len(in_file), len(files))
            return False
        # rename first (atomic), then delete: a kill never leaves half a journal behind
        gone = self.jdir.with_name(f"{self.jdir.name}.done-{os.getpid()}")
        try:
            rename_retrying(self.jdir, gone)
        except OSError as exc:  # FileHeldError included: the journal stays, harmless
            log.warning("%s: journal not removed (%s); the next nmsid command on this "
                        "session removes it", self.path, exc)
            return False
        shutil.rmtree(gone, ignore_errors=True)
        return True

    def check_space(self, need_bytes: int) -> None:
        """Refuse to start (before calibration) unless the folder holds ``need_bytes``
        plus the margin: the protocol's journal and the file's final version
        (:func:`expected_session_bytes`).

        Raises
        ------
        DiskFullError
            Naming the folder, the need and the free space.
        """
        need = int(need_bytes) + SPACE_MARGIN_BYTES
        free = free_bytes(self.path.parent)
        if free < need:
            raise DiskFullError(self.path, need, free, "the session (its journal and the "
                                "final file, with a 20 % margin)")

    def release(self) -> None:
        """Give up the writer lock (after the last write)."""
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def close(self, release: bool = True, publish: bool = True) -> None:
        """End writing: publish what is not yet in the file (best effort; the journal
        keeps it anyway), close the streams and (``release``) give up the lock."""
        self._close_partial()
        if publish and self._writer is not None and (
                self._writer.unpublished or self._events_in_h5 < len(self.events)):
            self.publish()
        if self._writer is not None:
            self._writer.close()
        if release:
            self.release()
        if not self._ev_fh.closed:
            try:
                self._ev_fh.flush()
                os.fsync(self._ev_fh.fileno())
            except OSError:
                pass
            self._ev_fh.close()


def file_trial_digests(path: Path) -> list[int]:
    """:func:`~nmsid.rig.journal.trial_digest` of every trial of a session file, in the
    file's order (``t001``, ``t002``, ...), read one trial at a time (only the four
    sample datasets, no attributes: the check after :func:`validate_session` at the end
    of a session, without a second full read of the file).

    Raises
    ------
    KeyError, OSError, RuntimeError
        As h5py does on a damaged file.
    """
    out = []
    with _h5py().File(path, "r") as f:
        trials = f["trials"]
        numbered = [(TRIAL_NAME_PATTERN.match(k), k) for k in trials]
        names = [k for m, k in sorted((int(m.group(1)), k) for m, k in numbered if m)]
        for name in names:
            g = trials[name]
            out.append(arrays_digest([g[k][()] for k in DIGEST_SIGNALS]))
    return out


def expected_session_bytes(n_trials: int, samples_per_trial: int, file_bytes: int = 0,
                           n_columns: int = 11) -> int:
    """Disk space a session needs, with a 20 % margin: each trial once in the journal and
    once in the new version of the file published at the end (both stored as float64 at
    worst: incompressible data), plus, when resuming, the file already there until the new
    version replaces it; ``n_columns``: rE, two currents, force, a 6-axis wrench and
    sync. Compressible data (A/D counts) needs far less (docs/benchmarks.md)."""
    trial = 8 * int(samples_per_trial) * int(n_columns) + 64 * 1024
    return int(1.2 * (int(n_trials) * trial * 2 + 2 * int(file_bytes))) + (4 << 20)


def check_new_session_path(path: Path) -> None:
    """Refuse a new session where a file or journal exists, naming a live writer."""
    writer = live_writer(path)
    if writer is not None and writer.pid != os.getpid():
        raise SessionLockedError(path, writer.describe())
    if os.path.lexists(path):
        raise SessionExistsError(path)
    if os.path.lexists(journal_dir(path)):
        raise SessionExistsError(journal_dir(path))


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
    extra = json.loads(json.dumps(extra, default=json_default))
    header = {"participant": s.participant, "created_utc": s.created_utc,
              "software": s.software, "config_json": s.config_json, "seed": s.seed,
              "backend": s.backend, "extra_attrs": extra, "file": path.name}
    write_durable(jdir / "header.json",
                   lambda fh: fh.write(json.dumps(header, indent=1,
                                                  default=json_default).encode("utf-8")))
    save_calibration(jdir / "calibration.npz", s.calibration)
    for i, t in enumerate(s.trials):
        save_trial_npz(jdir / f"trial-{i + 1:04d}.npz", t)
    with open(jdir / "events.jsonl", "w", encoding="utf-8") as fh:
        for ev in s.events:
            fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind, "detail": ev.detail}) + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    rename_retrying(jdir, final)
    fsync_dir(final.parent)
