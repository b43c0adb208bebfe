"""Checking a session file against the contract: :func:`validate_session`."""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path

import numpy as np

from protocols.session_model import (CALIBRATION_ATTRS, FORMAT, FORMAT_VERSION,
                                     OPTIONAL_SIGNALS, PARTICIPANT_PATTERN, ROOT_ATTRS,
                                     STATUSES, TRIAL_DATASETS, TRIAL_FLOAT_ATTRS,
                                     TRIAL_STR_ATTRS, _DAMAGE_ERRORS, Calibration, _as_float,
                                     _as_str, _h5py, _trial_names)

def validate_session(path: str | os.PathLike, *, fatal_only: bool = False) -> list[str]:
    """Check a file against the session-file contract.

    Parameters
    ----------
    path : path-like
        The file to check.
    fatal_only : bool
        Only report problems that prevent reading (missing items, wrong types), not
        inconsistent values.

    Returns
    -------
    list of str
        One human-readable line per violation, each naming the item; empty if valid.
    """
    path = Path(path)
    if not path.exists():
        return ["no such file"]
    try:
        f = _h5py().File(path, "r")
    except OSError as exc:
        return [f"cannot be opened as HDF5 ({exc}); if it was being written when a program "
                "stopped, try `nmsid recover`"]
    with f:
        try:
            return _problems(f, fatal_only)
        except _DAMAGE_ERRORS as exc:  # an object the structural checks reached is torn
            return [f"damaged: an item cannot be read ({type(exc).__name__}: {exc}); if it "
                    "was being written when a program stopped, try `nmsid recover`"]


def _problems(f, fatal_only: bool) -> list[str]:
    """The contract violations of an open file (see :func:`validate_session`)."""
    out: list[str] = []
    _validate_root(f, out, fatal_only)
    if "calibration" not in f or not isinstance(f["calibration"], _h5py().Group):
        out.append("missing required group /calibration")
    else:
        _validate_calibration(f["calibration"], out, fatal_only)
    if "trials" not in f or not isinstance(f["trials"], _h5py().Group):
        out.append("missing required group /trials")
    else:
        _validate_trials(f["trials"], out, fatal_only)
    return out


def _validate_root(f, out: list[str], fatal_only: bool) -> None:
    a = f.attrs
    for name in ROOT_ATTRS:
        if name not in a:
            out.append(f"missing required root attribute {name!r}")
    if "format" in a and _as_str(a["format"]) != FORMAT:
        out.append(f"root attribute format is {_as_str(a['format'])!r}, expected {FORMAT!r}")
    if "format_version" in a:
        try:
            v = int(np.asarray(a["format_version"]))
        except (TypeError, ValueError):
            v = None
        if v != FORMAT_VERSION:
            shown = v if v is not None else _as_str(a["format_version"])
            out.append(f"root attribute format_version is {shown}, this reader "
                       f"knows version {FORMAT_VERSION}")
    if not fatal_only and "participant" in a:
        p = _as_str(a["participant"])
        if not PARTICIPANT_PATTERN.match(p):
            out.append(f"root attribute participant {p!r} is not [A-Za-z0-9_-]{{1,64}}")
    if not fatal_only and "created_utc" in a and not _is_utc(_as_str(a["created_utc"])):
        out.append(f"root attribute created_utc {_as_str(a['created_utc'])!r} is not ISO 8601 "
                   "UTC like 2026-11-22T01:30:00Z")


def _is_utc(text: str) -> bool:
    try:
        t = _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return False
    return t.utcoffset() == _dt.timedelta(0)


def _validate_calibration(g, out: list[str], fatal_only: bool) -> None:
    values = {}
    for name in CALIBRATION_ATTRS:
        if name not in g.attrs:
            out.append(f"missing required attribute /calibration/{name}")
            continue
        try:
            values[name] = _as_float(g.attrs[name])
        except (TypeError, ValueError):
            out.append(f"/calibration attribute {name} is not a number: {g.attrs[name]!r}")
    if not fatal_only and len(values) == len(CALIBRATION_ATTRS):
        out.extend(Calibration(**values).problems())


def _validate_trials(g, out: list[str], fatal_only: bool) -> None:
    h5py = _h5py()
    names = _trial_names(g)
    others = [k for k in g if k not in names]
    if others and not fatal_only:
        out.append(f"/trials holds {others} which are not named t001, t002, ...")
    if not fatal_only:
        expected = [f"t{i + 1:03d}" for i in range(len(names))]
        if names != expected:
            out.append(f"/trials groups must be numbered t001, t002, ... without gaps; found "
                       f"{names[:5]}{'...' if len(names) > 5 else ''}")
    for name in names:
        where = f"/trials/{name}"
        try:
            t = g[name]
        except _DAMAGE_ERRORS as exc:
            out.append(f"{where} cannot be read ({type(exc).__name__}: {exc}); the file is "
                       "damaged (try `nmsid recover`)")
            continue
        if not isinstance(t, h5py.Group):
            out.append(f"{where} is not a group")
            continue
        for key in TRIAL_FLOAT_ATTRS:
            if key not in t.attrs:
                out.append(f"missing required attribute {where}/{key}")
            else:
                try:
                    _as_float(t.attrs[key])
                except (TypeError, ValueError):
                    out.append(f"{where} attribute {key} is not a number: {t.attrs[key]!r}")
        if "repeat" not in t.attrs:
            out.append(f"missing required attribute {where}/repeat")
        for key in TRIAL_STR_ATTRS:
            if key not in t.attrs:
                out.append(f"missing required attribute {where}/{key}")
        lengths = {}
        for key in TRIAL_DATASETS:
            if key not in t:
                out.append(f"missing required dataset {where}/{key}")
                continue
            d = t[key]
            if not isinstance(d, h5py.Dataset) or d.ndim != 1:
                out.append(f"{where}/{key} must be a 1-D dataset, got "
                           f"{getattr(d, 'shape', 'a group')}")
                continue
            if not np.issubdtype(d.dtype, np.floating):
                out.append(f"{where}/{key} must be float64, got {d.dtype}")
            lengths[key] = d.shape[0]
        if len(set(lengths.values())) > 1:
            out.append(f"{where} datasets differ in length: "
                       + ", ".join(f"{k}={v}" for k, v in lengths.items())
                       + " (all must have the same N)")
        if fatal_only:
            continue
        status = _as_str(t.attrs.get("status", "completed"))
        if "status" in t.attrs and status not in STATUSES:
            out.append(f"{where} status {status!r} is not 'completed' or 'aborted'")
        if status == "completed" and _as_str(t.attrs.get("abort_reason", "")):
            out.append(f"{where} is completed but has a non-empty abort_reason")
        if status == "aborted" and "abort_reason" in t.attrs and \
                not _as_str(t.attrs["abort_reason"]):
            out.append(f"{where} is aborted but abort_reason is empty (say why)")
        try:
            if "sE" in t.attrs and not 0 < _as_float(t.attrs["sE"]) <= 1:
                out.append(f"{where} sE = {_as_float(t.attrs['sE']):g} is outside (0, 1]")
            if "fs_Hz" in t.attrs and not _as_float(t.attrs["fs_Hz"]) > 0:
                out.append(f"{where} fs_Hz must be > 0")
        except (TypeError, ValueError):
            pass
        if "repeat" in t.attrs:
            try:
                if int(np.asarray(t.attrs["repeat"])) < 1:
                    out.append(f"{where} repeat must be 1, 2, 3, ...")
            except (TypeError, ValueError):
                out.append(f"{where} repeat is not an integer: {t.attrs['repeat']!r}")
        if "started_utc" in t.attrs and _as_str(t.attrs["started_utc"]) and \
                not _is_utc(_as_str(t.attrs["started_utc"])):
            out.append(f"{where} started_utc {_as_str(t.attrs['started_utc'])!r} is not ISO "
                       "8601 UTC")
        if "wrench" in t and lengths:
            n = next(iter(lengths.values()))
            if t["wrench"].shape != (n, 6):
                out.append(f"{where}/wrench must have shape ({n}, 6), got {t['wrench'].shape}")
        if "sync" in t and lengths:
            n = next(iter(lengths.values()))
            if t["sync"].shape != (n,):
                out.append(f"{where}/sync must have shape ({n},), got {t['sync'].shape}")
        for key in OPTIONAL_SIGNALS:
            if key in t and isinstance(t[key], h5py.Dataset) and \
                    np.issubdtype(t[key].dtype, np.integer) and "scale" not in t[key].attrs:
                out.append(f"{where}/{key} holds integer counts without a 'scale' attribute "
                           "(value = offset + scale * count)")

