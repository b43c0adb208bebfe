"""The write-ahead journal's file layout: ``<file>.journal/`` beside a session file.

See :mod:`nmsid.rig.session_log` for what each file holds and why. This module only knows how
to write and read them durably; :mod:`nmsid.rig.recovery` and
:class:`nmsid.rig.session_log.SessionLog` use it.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import errno
import json
import os
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.protocols.errors import DiskFullError, SessionWriteError
from nmsid.protocols.session_codec import counts_to_values
from nmsid.protocols.session_file import Calibration, Event, SessionFileError, Trial
from nmsid.protocols.session_publish import (
    FileHeldError,
    free_bytes,
    fsync_dir,
    replace_retrying,
)
from nmsid.protocols.session_writer import as_counts_memo

PARTIAL_ABORT_REASON = "process ended during trial"
_TRIAL_FILE = re.compile(r"^trial-(\d{4,})\.npz$")
_TRIAL_META_FIELDS = [f.name for f in dataclasses.fields(Trial)
                      if f.name not in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench",
                                        "sync")]
_CAL_FIELDS = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")
PARTIAL_COLUMNS = ("force_N", "rE", "I_ext_mA", "I_flex_mA")


def utc_now_ms() -> str:
    """The current time as ISO 8601 UTC with milliseconds (event time stamps)."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def journal_dir(path: str | os.PathLike) -> Path:
    """The journal directory of a session file: ``<file>.journal``."""
    p = Path(path)
    return p.with_name(p.name + ".journal")


# -- durable small writes ----------------------------------------------------------------
class JournalEntryError(SessionFileError):
    """One journal file cannot be read (truncated by a kill, damaged on disk)."""


def disk_error(path: Path, exc: OSError, need_bytes: int = 0,
               doing: str = "") -> SessionFileError:
    """The one-line error for a refused write of ``path``: a full disk names the folder,
    the need and the free space."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        try:
            free = free_bytes(path.parent)
        except OSError:
            free = 0
        return DiskFullError(path, max(need_bytes, free + 1), free,
                             doing or f"writing {path.name}")
    return SessionWriteError(path, f"cannot be written ({exc.strerror or exc})")


def write_durable(target: Path, write) -> None:
    """Write via ``write(fileobj)`` to a temp file, fsync, rename onto ``target``.

    The rename is retried on Windows while a scanner or indexer holds the new file
    (:func:`nmsid.protocols.session_publish.replace_retrying`).

    Raises
    ------
    DiskFullError, SessionWriteError
        If the system refuses the write (the temp file is removed, ``target`` unchanged).
    """
    tmp = target.with_name(target.name + ".tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        replace_retrying(tmp, target)
    except FileHeldError:
        _unlink_quietly(tmp)
        raise
    except OSError as exc:
        _unlink_quietly(tmp)
        raise disk_error(target, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    fsync_dir(target.parent)


def _unlink_quietly(p: Path) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


def json_default(obj):
    """``json.dumps`` helper for numpy scalars / arrays and bytes."""
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
                                 default=json_default))


_SIGNALS = ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync")


def save_trial_npz(target: Path, trial: Trial) -> None:
    """Write a trial (arrays + metadata as JSON) durably with :func:`numpy.savez_compressed`:
    temp file, flush, fsync, rename, fsync of the folder (:func:`write_durable`).

    The arrays are encoded the way the session file stores them, so the journal takes
    about as much disk as the file (``bench/bench_store.py``: peak disk of a session at
    most 2x the final file): an optional signal on an exact A/D grid (``wrench``,
    ``sync``) as integer counts with its scale (bit-exact,
    :func:`nmsid.protocols.session_codec._as_counts`), every array byte-shuffled (HDF5's
    shuffle) before numpy deflates it. ``__enc__`` (JSON) says how to decode each one;
    :func:`load_trial_npz` also reads plain entries (no ``__enc__``).

    Measured on a simulated 15 s trial at 2 kHz with wrench and sync, 2 busy cores
    (``bench/bench_journal_entry.py``, encoding included): 42 ms of CPU, 0.66 MB. Stored
    members (``np.savez``) take 8 ms but 1.36 MB, and the peak disk of a session then
    grows to 2.9x the file (``bench_store.py --small``; target 2x). The zip writer of our
    own this replaced (a run-length deflate strategy numpy cannot ask for) took 18 ms for
    0.69 MB. A 45-trial fast-clock session (``bench/bench_session.py --seeds 1``, the
    same busy machine) took 6.0-6.7 s of CPU against 5.35 s with that writer: on the rig,
    where a trial lasts 15 s, 24 ms per trial end is nothing, and no container of our own
    is left to maintain. Its entries read as these do.
    """
    members: dict[str, Any] = trial_members(trial)  # Any: numpy's stubs type **kwds apart
    write_durable(target, lambda fh: np.savez_compressed(fh, **members))


def trial_members(trial: Trial) -> dict[str, np.ndarray]:
    """The members of a trial's journal entry (:func:`save_trial_npz`): each signal's
    shuffled bytes, ``__enc__`` (how to decode them) and ``__meta__`` (the attributes)."""
    meta = np.array(json.dumps(trial_meta(trial)))
    enc: dict[str, dict[str, Any]] = {}
    members: dict[str, np.ndarray] = {}
    for k in _SIGNALS:
        values = getattr(trial, k)
        if values is None:
            continue
        grid = as_counts_memo(values) if k in ("wrench", "sync") else None
        arr = np.ascontiguousarray(values, dtype=np.float64)
        info: dict[str, Any] = {"shape": list(arr.shape)}
        if grid is not None:
            counts, scale, offset = grid
            info.update(scale=np.asarray(scale).tolist(), offset=np.asarray(offset).tolist())
            arr = np.ascontiguousarray(counts)
        info["dtype"] = arr.dtype.str
        enc[k] = info
        # the shuffle filter: byte j of every element together (deflates far better)
        members[k] = arr.reshape(-1).view(np.uint8).reshape(-1, arr.dtype.itemsize).T.copy()
    members["__enc__"] = np.array(json.dumps(enc))
    members["__meta__"] = meta
    return members


def _decode(z, enc: dict[str, Any]) -> dict[str, np.ndarray]:
    out = {}
    for k, info in enc.items():
        dtype = np.dtype(info["dtype"])
        arr = np.ascontiguousarray(np.array(z[k]).T).view(dtype).reshape(info["shape"])
        if "scale" in info:
            arr = counts_to_values(arr, info["scale"], info["offset"])
        out[k] = np.asarray(arr, dtype=np.float64)
    return out


_NPZ_ERRORS = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile,
               zlib.error)
"""What reading a truncated or damaged ``.npz`` raises (BadZipFile, a short read, a bad
JSON or a missing member)."""


def _open_npz(path: Path, read):
    """``read(z)`` on the ``.npz`` at ``path``, with the file closed on every outcome.

    ``np.load(path)`` of a damaged zip raises with its own file object still open (it
    hands the handle to ``NpzFile`` before the zip is checked), and the exception's
    traceback keeps it alive in an ``except`` block: on Windows, a later ``os.replace``
    of that entry then fails with a sharing violation (Microsoft, "MoveFileExW"). Opening
    the file here, in a ``with`` block, closes it before the exception leaves.
    """
    with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
        return read(z)


def load_trial_npz(path: Path) -> Trial:
    """Read a trial written by :func:`save_trial_npz` (or by the zip writer before it: the
    same members).

    Raises
    ------
    JournalEntryError
        If the file is truncated or damaged (names the file).
    """
    def read(z):
        meta = json.loads(str(z["__meta__"]))
        if "__enc__" in z.files:
            arrays = _decode(z, json.loads(str(z["__enc__"])))
        else:
            arrays = {k: np.array(z[k]) for k in z.files if k != "__meta__"}
        return meta, arrays

    try:
        meta, arrays = _open_npz(path, read)
        kw = {k: v for k, v in meta.items() if k in _TRIAL_META_FIELDS}
        return Trial(**kw, **{k: arrays.get(k) for k in _SIGNALS})
    except _NPZ_ERRORS as exc:
        raise JournalEntryError(path, f"journal entry unreadable ({type(exc).__name__}: "
                                      f"{exc})") from None


def load_trial_meta(path: Path) -> dict[str, Any]:
    """Only the metadata of a journaled trial (raises :class:`JournalEntryError`)."""
    try:
        meta = _open_npz(path, lambda z: json.loads(str(z["__meta__"])))
        if not isinstance(meta, dict):
            raise TypeError("metadata is not an object")
        return meta
    except _NPZ_ERRORS as exc:
        raise JournalEntryError(path, f"journal entry unreadable ({type(exc).__name__}: "
                                      f"{exc})") from None


def save_calibration(target: Path, cal: Calibration) -> None:
    """Write the calibration (currents, forces, ramps) durably."""
    meta = np.array(json.dumps({k: float(getattr(cal, k)) for k in _CAL_FIELDS}))
    arrays: dict[str, Any] = {"__meta__": meta}
    arrays.update({f"ramp__{k}": np.asarray(v, dtype=float) for k, v in cal.ramps.items()})
    write_durable(target, lambda fh: np.savez(fh, **arrays))


def load_calibration(path: Path) -> Calibration:
    """Read a calibration written by :func:`save_calibration`."""
    try:
        meta, ramps = _open_npz(path, lambda z: (
            json.loads(str(z["__meta__"])),
            {k[len("ramp__"):]: np.array(z[k]) for k in z.files if k.startswith("ramp__")}))
        return Calibration(**{k: float(meta[k]) for k in _CAL_FIELDS}, ramps=ramps)
    except _NPZ_ERRORS as exc:
        raise JournalEntryError(path, f"journal calibration unreadable ({type(exc).__name__}:"
                                      f" {exc})") from None


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
    calibration_error: str = ""
    """Why ``calibration.npz`` could not be read (empty if it was, or is absent)."""

    def trial_metas(self) -> list[dict[str, Any]]:
        return [load_trial_meta(p) for p in self.trial_files]


def read_journal(jdir: Path, *, allow_gaps: bool = False) -> JournalContents:
    """Read a journal directory (tolerating a torn last event line).

    Parameters
    ----------
    allow_gaps : bool
        Accept trial entries not numbered 1, 2, ... (a deleted entry; recovery merges
        such a journal with the file).

    Raises
    ------
    SessionFileError
        If the header is missing or damaged (with what to do), or (``allow_gaps``
        False) an entry is missing.
    """
    header_path = jdir / "header.json"
    try:
        header = json.loads(header_path.read_text(encoding="utf-8"))
        if not isinstance(header, dict):
            raise TypeError("not a JSON object")
    except (OSError, ValueError, TypeError) as exc:
        state = "missing" if not header_path.exists() else f"damaged ({exc})"
        raise SessionFileError(header_path, f"is {state}; run `nmsid recover "
                                            f"{jdir.with_name(jdir.name[:-len('.journal')])}`"
                                            ", which rebuilds it from the session file"
                               ) from None
    cal = None
    cal_error = ""
    if (jdir / "calibration.npz").exists():
        try:
            cal = load_calibration(jdir / "calibration.npz")
        except JournalEntryError as exc:
            cal_error = exc.problem
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
                   key=lambda p: _entry_number(p.name))
    for i, p in enumerate(files):
        if not allow_gaps and _entry_number(p.name) != i + 1:
            raise SessionFileError(jdir, f"journal trial files are not numbered 1, 2, ... "
                                         f"(found {p.name} at position {i + 1})")
    pmeta = None
    if (jdir / "partial.json").exists():
        try:
            pmeta = json.loads((jdir / "partial.json").read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            pass  # torn by a kill: pmeta stays None
    if pmeta is not None and not (isinstance(pmeta, dict) and isinstance(
            pmeta.get("columns"), list) and set(PARTIAL_COLUMNS) <= set(pmeta["columns"])):
        pmeta = None  # metadata torn or from another version: nothing usable to stream into
    return JournalContents(header, cal, events, files, pmeta,
                           jdir / "partial.f64" if pmeta is not None else None,
                           calibration_error=cal_error)


def _entry_number(name: str) -> int:
    """The number of a journal entry's name ``trial-NNNN.npz`` (which it must match)."""
    m = _TRIAL_FILE.match(name)
    if m is None:
        raise ValueError(f"{name!r} is not a journal trial entry")
    return int(m.group(1))


def partial_trial(jc: JournalContents) -> Trial:
    """The streamed trial in progress as an aborted trial (whole rows only; a row torn
    by a kill is dropped)."""
    if jc.partial_meta is None:
        raise ValueError("the journal holds no trial in progress")
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
DIGEST_SIGNALS = ("rE", "I_ext_mA", "I_flex_mA", "force_N")
"""The sample arrays :func:`trial_digest` covers, in its order."""


def trial_digest(trial: Trial) -> int:
    """CRC-32 of a trial's four sample arrays (as float64)."""
    return arrays_digest([getattr(trial, k) for k in DIGEST_SIGNALS])


def arrays_digest(arrays) -> int:
    """CRC-32 of the arrays (as float64) of :data:`DIGEST_SIGNALS`, in that order."""
    crc = 0
    for values in arrays:
        crc = zlib.crc32(np.ascontiguousarray(values, dtype=np.float64).data, crc)
    return crc


def append_event_line(jdir: Path, ev: Event) -> None:
    """Append one event to ``events.jsonl``."""
    with open(jdir / "events.jsonl", "a", encoding="utf-8") as fh:
        fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind, "detail": ev.detail}) + "\n")
        fh.flush()


# -- the logger the engine uses ----------------------------------------------------------
