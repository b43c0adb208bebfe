"""The write-ahead journal's file layout: ``<file>.journal/`` beside a session file.

See :mod:`nmsid.rig.session_log` for what each file holds and why. This module only knows how
to write and read them durably; :mod:`nmsid.rig.recovery` and :class:`nmsid.rig.session_log.SessionLog`
use it.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.protocols.session_file import Calibration, Event, SessionFileError, Trial

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
def fsync_dir(d: Path) -> None:
    """Make a rename inside ``d`` durable (fsync of the folder; best effort)."""
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


def write_durable(target: Path, write) -> None:
    """Write via ``write(fileobj)`` to a temp file, fsync, rename onto ``target``."""
    tmp = target.with_name(target.name + ".tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, target)
    fsync_dir(target.parent)


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


def save_trial_npz(target: Path, trial: Trial) -> None:
    """Write a trial (arrays + metadata as JSON) durably: temp file, fsync, rename."""
    arrays = {k: np.asarray(getattr(trial, k), dtype=np.float64)
              for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N")}
    if trial.wrench is not None:
        arrays["wrench"] = np.asarray(trial.wrench, dtype=np.float64)
    if trial.sync is not None:
        arrays["sync"] = np.asarray(trial.sync, dtype=np.float64)
    meta = np.array(json.dumps(trial_meta(trial)))
    write_durable(target, lambda fh: np.savez(fh, __meta__=meta, **arrays))


def load_trial_npz(path: Path) -> Trial:
    """Read a trial written by :func:`save_trial_npz`."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["__meta__"]))
        arrays = {k: np.array(z[k]) for k in z.files if k != "__meta__"}
    kw = {k: v for k, v in meta.items() if k in _TRIAL_META_FIELDS}
    return Trial(**kw, **{k: arrays.get(k) for k in ("rE", "I_ext_mA", "I_flex_mA",
                                                       "force_N", "wrench", "sync")})


def save_calibration(target: Path, cal: Calibration) -> None:
    """Write the calibration (currents, forces, ramps) durably."""
    meta = np.array(json.dumps({k: float(getattr(cal, k)) for k in _CAL_FIELDS}))
    ramps = {f"ramp__{k}": np.asarray(v, dtype=float) for k, v in cal.ramps.items()}
    write_durable(target, lambda fh: np.savez(fh, __meta__=meta, **ramps))


def load_calibration(path: Path) -> Calibration:
    """Read a calibration written by :func:`save_calibration`."""
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
        cal = load_calibration(jdir / "calibration.npz")
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


def partial_trial(jc: JournalContents) -> Trial:
    """The streamed trial in progress as an aborted trial (whole rows only; a row torn
    by a kill is dropped)."""
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
def trial_digest(trial: Trial) -> int:
    """CRC-32 of a trial's four sample arrays (as float64)."""
    crc = 0
    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N"):
        crc = zlib.crc32(np.ascontiguousarray(getattr(trial, k), dtype=np.float64).tobytes(),
                         crc)
    return crc


def append_event_line(jdir: Path, ev: Event) -> None:
    """Append one event to ``events.jsonl``."""
    with open(jdir / "events.jsonl", "a", encoding="utf-8") as fh:
        fh.write(json.dumps({"utc": ev.utc, "kind": ev.kind, "detail": ev.detail}) + "\n")
        fh.flush()


# -- the logger the engine uses ----------------------------------------------------------
