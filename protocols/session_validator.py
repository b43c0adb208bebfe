"""Checking a session file against the contract: :func:`validate_session`.

Three passes: links (external / soft links, external storage, virtual datasets: refused,
never followed), structure and values (every attribute's type, range and finiteness,
printable names), then the data (every dataset read, its Fletcher-32 checksum verified,
its values checked). :func:`read_session` runs the first two and refuses a file with a
problem that makes its values unusable (``fatal_only``).
"""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path

import numpy as np

from nmsid.protocols.session_checks import (FS_RANGE_Hz, MAX_CARRIER_Hz, MAX_TRIAL_S,
                                            is_int_attr, is_number_attr, link_problems, max_current_mA,
                                            number_problem, printable_problem, samples_problems,
                                            short_repr)
from nmsid.protocols.session_model import (CALIBRATION_ATTRS, FORMAT, FORMAT_VERSION,
                                           OPTIONAL_SIGNALS, PARTICIPANT_PATTERN, ROOT_ATTRS,
                                           STATUSES, TRIAL_DATASETS, TRIAL_FLOAT_ATTRS,
                                           TRIAL_STR_ATTRS, _DAMAGE_ERRORS, _as_float, _as_str,
                                           _h5py, _trial_names)


def validate_session(path: str | os.PathLike, *, fatal_only: bool = False,
                     read_data: bool = True) -> list[str]:
    """Check a file against the session-file contract.

    Parameters
    ----------
    path : path-like
        The file to check.
    fatal_only : bool
        Only report problems that make the file unusable (missing items, wrong types,
        values out of range, links), not cosmetic ones (time formats, numbering).
    read_data : bool
        Also read every dataset (checksums, values); a damaged file is never valid.

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
            out = _problems(f, fatal_only)
            if read_data and not any(p.startswith("/") and "link" in p for p in out):
                out += _data_problems(f)
            return out
        except _DAMAGE_ERRORS as exc:  # an object the structural checks reached is torn
            return [f"damaged: an item cannot be read ({type(exc).__name__}: {exc}); if it "
                    "was being written when a program stopped, try `nmsid recover`"]


def _problems(f, fatal_only: bool) -> list[str]:
    """The contract violations of an open file (see :func:`validate_session`)."""
    links = link_problems(f)
    if links:
        return links  # nothing else is looked at: that could follow a link
    out: list[str] = []
    _validate_root(f, out, fatal_only)
    if "calibration" not in f or not isinstance(f["calibration"], _h5py().Group):
        out.append("missing required group /calibration")
    else:
        _validate_calibration(f["calibration"], out, _max_current(f))
    if "trials" not in f or not isinstance(f["trials"], _h5py().Group):
        out.append("missing required group /trials")
    else:
        _validate_trials(f["trials"], out, fatal_only)
    if "events" in f and isinstance(f["events"], _h5py().Group):
        _validate_events(f["events"], out)
    return out


def _max_current(f) -> float:
    return max_current_mA(_as_str(f.attrs.get("config_json", "")))


def _validate_root(f, out: list[str], fatal_only: bool) -> None:
    a = f.attrs
    for name in ROOT_ATTRS:
        if name not in a:
            out.append(f"missing required root attribute {name!r}")
    for name in ("format", "participant", "created_utc", "software", "backend"):
        if name in a:
            p = printable_problem("root", name, a[name])
            if p:
                out.append(p)
    if "format" in a and _as_str(a["format"]) != FORMAT:
        out.append(f"root attribute format is {_as_str(a['format'])!r}, expected {FORMAT!r}")
    if "format_version" in a:
        v = int(np.asarray(a["format_version"]).reshape(())) \
            if is_int_attr(a["format_version"]) else None
        if v != FORMAT_VERSION:
            shown = v if v is not None else repr(_as_str(a["format_version"]))
            out.append(f"root attribute format_version is {shown}, this reader "
                       f"knows version {FORMAT_VERSION} (an integer)")
    if "participant" in a:
        p = _as_str(a["participant"])
        if not PARTICIPANT_PATTERN.match(p):
            out.append(f"root attribute participant {p!r} is not [A-Za-z0-9_-]{{1,64}}")
    if "seed" in a and not is_int_attr(a["seed"]):
        out.append(f"root attribute seed = {a['seed']!r} is not an integer")
    if not fatal_only and "created_utc" in a and not _is_utc(_as_str(a["created_utc"])):
        out.append(f"root attribute created_utc {_as_str(a['created_utc'])!r} is not ISO 8601 "
                   "UTC like 2026-11-22T01:30:00Z")


def _is_utc(text: str) -> bool:
    try:
        t = _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return False
    return t.utcoffset() == _dt.timedelta(0)


def _validate_calibration(g, out: list[str], max_mA: float) -> None:
    values = {}
    for name in CALIBRATION_ATTRS:
        if name not in g.attrs:
            out.append(f"missing required attribute /calibration/{name}")
            continue
        if name.endswith("_mA"):
            p = number_problem("/calibration", name, g.attrs[name], None, max_mA,  # >= 0:
                               valid=f"[0, {max_mA:g}] mA (the stimulator's range)")  # below
        else:
            p = number_problem("/calibration", name, g.attrs[name], 0.0, 1000.0,
                               valid="[0, 1000] N")
        if p:
            out.append(p)
        if is_number_attr(g.attrs[name]) and np.isfinite(_as_float(g.attrs[name])):
            values[name] = _as_float(g.attrs[name])
    if {"Iemin_mA", "Iemax_mA"} <= set(values) and not (
            values["Iemax_mA"] > values["Iemin_mA"] >= 0):
        out.append(f"/calibration needs Iemax_mA > Iemin_mA >= 0, got Iemin_mA="
                   f"{values['Iemin_mA']:g}, Iemax_mA={values['Iemax_mA']:g}")
    if {"Ifmin_mA", "Ifmax_mA"} <= set(values) and not (
            values["Ifmax_mA"] > values["Ifmin_mA"] >= 0):
        out.append(f"/calibration needs Ifmax_mA > Ifmin_mA >= 0, got Ifmin_mA="
                   f"{values['Ifmin_mA']:g}, Ifmax_mA={values['Ifmax_mA']:g}")
    if {"Fmin_N", "Fmax_N"} <= set(values) and not values["Fmax_N"] > values["Fmin_N"]:
        out.append(f"/calibration needs Fmax_N > Fmin_N, got Fmin_N={values['Fmin_N']:g}, "
                   f"Fmax_N={values['Fmax_N']:g}")


_TRIAL_RANGES = {
    "sE": (0.0, 1.0, True, "(0, 1]"),
    "fs_Hz": (FS_RANGE_Hz[0], FS_RANGE_Hz[1], False,
              f"[{FS_RANGE_Hz[0]:g}, {FS_RANGE_Hz[1]:g}] Hz"),
    "steady_s": (0.0, MAX_TRIAL_S, False, f"[0, {MAX_TRIAL_S:g}] s"),
    "chirp_s": (0.0, MAX_TRIAL_S, True, f"(0, {MAX_TRIAL_S:g}] s"),
    "chirp_f0_Hz": (0.0, FS_RANGE_Hz[1] / 2, True, "(0, fs_Hz / 2] Hz"),
    "chirp_f1_Hz": (0.0, FS_RANGE_Hz[1] / 2, True, "(0, fs_Hz / 2] Hz"),
    "carrier_Hz": (0.0, MAX_CARRIER_Hz, True, f"(0, {MAX_CARRIER_Hz:g}] Hz"),
}


def _validate_trials(g, out: list[str], fatal_only: bool) -> None:
    h5py = _h5py()
    names = _trial_names(g)
    others = [k for k in g if k not in names]
    if others and not fatal_only:
        out.append(f"/trials holds {[repr(k) for k in others[:5]]} which are not named "
                   "t001, t002, ...")
    if not fatal_only:
        expected = [f"t{i + 1:03d}" for i in range(len(names))]
        if names != expected:
            out.append(f"/trials groups must be numbered t001, t002, ... without gaps; found "
                       f"{names[:5]}{'...' if len(names) > 5 else ''}")
    for name in names:
        where = f"/trials/{name}"
        t = g[name]
        if not isinstance(t, h5py.Group):
            out.append(f"{where} is not a group")
            continue
        _validate_trial_attrs(t, where, out, fatal_only)
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
        n = next(iter(lengths.values())) if lengths else None
        for key, shape in (("wrench", (n, 6)), ("sync", (n,))):
            if key in t and n is not None:
                d = t[key]
                if not isinstance(d, h5py.Dataset) or d.shape != shape:
                    out.append(f"{where}/{key} must have shape {shape}, got "
                               f"{getattr(d, 'shape', 'a group')}")
                elif d.dtype.kind not in "iuf":
                    out.append(f"{where}/{key} must be numeric, got {d.dtype}")
        for key in OPTIONAL_SIGNALS:
            if key in t and isinstance(t[key], h5py.Dataset) and \
                    np.issubdtype(t[key].dtype, np.integer) and "scale" not in t[key].attrs:
                out.append(f"{where}/{key} holds integer counts without a 'scale' attribute "
                           "(value = offset + scale * count)")


def _validate_trial_attrs(t, where: str, out: list[str], fatal_only: bool) -> None:
    a = t.attrs
    for key in TRIAL_FLOAT_ATTRS:
        if key not in a:
            out.append(f"missing required attribute {where}/{key}")
            continue
        low, high, low_open, valid = _TRIAL_RANGES[key]
        p = number_problem(where, key, a[key], low, high, low_open=low_open, valid=valid)
        if p:
            out.append(p)
    if "repeat" not in a:
        out.append(f"missing required attribute {where}/repeat")
    elif not is_int_attr(a["repeat"]) or int(np.asarray(a["repeat"]).reshape(())) < 1:
        out.append(f"{where} attribute repeat = {short_repr(a['repeat'])} is not valid: an "
                   "integer 1, 2, 3, ...")
    for key in TRIAL_STR_ATTRS:
        if key not in a:
            out.append(f"missing required attribute {where}/{key}")
        else:
            p = printable_problem(where, key, a[key])
            if p:
                out.append(p)
    for key in ("chirp_f1_Hz", "chirp_f0_Hz"):
        try:
            if key in a and "fs_Hz" in a and _as_float(a[key]) > _as_float(a["fs_Hz"]) / 2:
                out.append(f"{where} attribute {key} = {_as_float(a[key]):g} is above "
                           f"fs_Hz / 2 = {_as_float(a['fs_Hz']) / 2:g}")
        except (TypeError, ValueError):
            pass
    status = _as_str(a.get("status", "completed"))
    if "status" in a and status not in STATUSES:
        out.append(f"{where} status {status!r} is not 'completed' or 'aborted'")
    if fatal_only:
        return
    if status == "completed" and _as_str(a.get("abort_reason", "")):
        out.append(f"{where} is completed but has a non-empty abort_reason")
    if status == "aborted" and "abort_reason" in a and not _as_str(a["abort_reason"]):
        out.append(f"{where} is aborted but abort_reason is empty (say why)")
    if "started_utc" in a and _as_str(a["started_utc"]) and \
            not _is_utc(_as_str(a["started_utc"])):
        out.append(f"{where} started_utc {_as_str(a['started_utc'])!r} is not ISO 8601 UTC")


def _validate_events(g, out: list[str]) -> None:
    h5py = _h5py()
    for key in g:
        e = g[key]
        if not isinstance(e, h5py.Group):
            continue
        for name in ("utc", "kind", "detail"):
            if name in e.attrs:
                p = printable_problem(f"/events/{key}", name, e.attrs[name])
                if p:
                    out.append(p)


def _trial_n_max(t) -> int | None:
    """Most samples a trial may hold: 4 x (steady_s + chirp_s) * fs_Hz + 10**6 (the
    contract sets no upper length; this bounds what a damaged or hostile file may make a
    reader allocate)."""
    try:
        fs = _as_float(t.attrs["fs_Hz"])
        dur = _as_float(t.attrs["steady_s"]) + _as_float(t.attrs["chirp_s"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.isfinite(fs) and np.isfinite(dur)) or fs <= 0 or dur < 0:
        return None
    return int(4 * min(dur, MAX_TRIAL_S) * min(fs, FS_RANGE_Hz[1])) + 10 ** 6


def _data_problems(f) -> list[str]:
    """Read every dataset this validator vouches for (block by block: bounded memory)
    and check its values; a damaged chunk or checksum mismatch is reported."""
    h5py = _h5py()
    out: list[str] = []
    max_mA = _max_current(f)
    cal = f.get("calibration")
    if isinstance(cal, h5py.Group):
        for key in cal:
            if isinstance(cal[key], h5py.Dataset):
                out += samples_problems("/calibration", cal[key], max_current=max_mA,
                                        n_max=None)
    trials = f.get("trials")
    if isinstance(trials, h5py.Group):
        for name in _trial_names(trials):
            t = trials[name]
            if not isinstance(t, h5py.Group):
                continue
            n_max = _trial_n_max(t)
            for key in (*TRIAL_DATASETS, *OPTIONAL_SIGNALS):
                if key in t and isinstance(t[key], h5py.Dataset):
                    out += samples_problems(f"/trials/{name}", t[key], max_current=max_mA,
                                            n_max=n_max)
    return out
