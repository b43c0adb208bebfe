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

from nmsid.protocols.session_checks import (
    MAX_TRIAL_S,
    FS_RANGE_Hz,
    _is_str_attr,
    calibration_findings,
    is_int_attr,
    link_problems,
    max_current_mA,
    printable_problem,
    samples_problems,
    trial_attr_findings,
)
from nmsid.protocols.session_h5 import Member, has_attr, open_group, open_member, read_attrs
from nmsid.protocols.session_model import (
    _DAMAGE_ERRORS,
    FORMAT,
    FORMAT_VERSION,
    OPTIONAL_SIGNALS,
    PARTICIPANT_PATTERN,
    ROOT_ATTRS,
    TRIAL_DATASETS,
    _as_float,
    _as_str,
    _h5py,
    _trial_names,
)


def validate_session(path: str | os.PathLike, *, fatal_only: bool = False,
                     read_data: bool = True, warnings: list[str] | None = None) -> list[str]:
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
    warnings : list of str, optional
        Receives one line per implausible value the contract allows (a current above the
        recording stimulator's range, a force beyond an elbow's, ...): such a file is valid.

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
            out = _problems(f, fatal_only, warnings)
            if read_data and not any(p.startswith("/") and "link" in p for p in out):
                out += _data_problems(f, warnings)
            return out
        except _DAMAGE_ERRORS as exc:  # an object the structural checks reached is torn
            return [f"damaged: an item cannot be read ({type(exc).__name__}: {exc}); if it "
                    "was being written when a program stopped, try `nmsid recover`"]


class AttrSnapshot:
    """Each object's attributes read once, as plain dicts, for one pass over an open file.

    An HDF5 attribute read through h5py's high-level API costs ~20 us, and the checks read
    many attributes several times; the reader then needs them again. The validator fills a
    snapshot (through :func:`nmsid.protocols.session_h5.read_attrs`, ~3x cheaper per
    attribute) and :func:`read_session` reuses it, with the trial members the checks opened:
    a 45-trial session's ~1400 attributes are read once instead of ~3400 times.
    """

    def __init__(self) -> None:
        self._attrs: dict[str, dict] = {}
        self.events: dict[str, dict] | None = None
        """Event group name -> its ``utc``/``kind``/``detail`` attributes (those present),
        filled by the events' check."""
        self.members: dict[str, dict[str, Member]] = {}
        """Trial name -> the members the structural checks found (``rE``, ...), as
        described when opened (their ids closed: ``Member.id`` None)."""

    def of(self, obj) -> dict:
        """``obj``'s attributes as a dict (read on the first call for ``obj.name``)."""
        return self.of_id(obj.name, obj.id)

    def cached(self, key: str) -> dict | None:
        """The attributes of the object at path ``key`` if read already, else None."""
        return self._attrs.get(key)

    def of_id(self, key: str, oid) -> dict:
        """The attributes of the low-level object ``oid`` at path ``key`` (read once)."""
        found = self._attrs.get(key)
        if found is None:
            found = self._attrs[key] = read_attrs(oid)
        return found


def _problems(f, fatal_only: bool, warnings: list[str] | None = None,
              snapshot: AttrSnapshot | None = None) -> list[str]:
    """The contract violations of an open file (see :func:`validate_session`); warnings
    (implausible, allowed) go to ``warnings``; the attributes read land in ``snapshot``
    (for a reader that needs them next)."""
    links = link_problems(f)
    if links:
        return links  # nothing else is looked at: that could follow a link
    snap = snapshot if snapshot is not None else AttrSnapshot()
    out: list[str] = []
    warn: list[str] = [] if warnings is None else warnings
    _validate_root(f, out, fatal_only, warn, snap)
    cal = f.get("calibration")
    if not isinstance(cal, _h5py().Group):
        out.append("missing required group /calibration")
    else:
        found = calibration_findings(snap.of(cal), _max_current(f, snap))
        out += found.problems
        warn += found.warnings
    trials = f.get("trials")
    if not isinstance(trials, _h5py().Group):
        out.append("missing required group /trials")
    else:
        _validate_trials(trials, out, fatal_only, warn, snap)
    events = f.get("events")
    if isinstance(events, _h5py().Group):
        _validate_events(events, warn, snap)
    return out


def _max_current(f, snap: AttrSnapshot | None = None) -> float:
    a = snap.of(f) if snap is not None else f.attrs
    return max_current_mA(_as_str(a.get("config_json", "")))


def _validate_root(f, out: list[str], fatal_only: bool, warn: list[str],
                   snap: AttrSnapshot) -> None:
    a = snap.of(f)
    for name in ROOT_ATTRS:
        if name not in a:
            out.append(f"missing required root attribute {name!r}")
    for name in ("format", "participant", "created_utc", "software", "backend"):
        if name in a:
            if not _is_str_attr(a[name]):
                out.append(f"root attribute {name} = {a[name]!r} is not a string")
                continue
            p = printable_problem("root", name, a[name])
            if p and name != "participant":  # the participant's pattern refuses it
                warn.append(p)
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


def _validate_trials(g, out: list[str], fatal_only: bool, warn: list[str],
                     snap: AttrSnapshot) -> None:
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
        tid = open_group(g.id, name)
        if tid is None:
            out.append(f"{where} is not a group")
            continue
        _validate_trial_attrs(snap.of_id(where, tid), where, out, fatal_only, warn)
        # each member opened once, low-level (h5py's group[name] builds a File object
        # per call), and closed with this trial: HDF5 then reuses one trial's memory for
        # the next (holding ~270 datasets open at once cost a fresh process ~7 ms of page
        # faults); the reader learns their shapes and types from the snapshot
        members = {k: open_member(tid, k) for k in _group_names(tid) if k in _CHECKED}
        snap.members[name] = {k: m.closed() for k, m in members.items()}
        lengths = {}
        for key in TRIAL_DATASETS:
            if key not in members:
                out.append(f"missing required dataset {where}/{key}")
                continue
            d = members[key]
            if not d.is_dataset or d.ndim != 1:
                out.append(f"{where}/{key} must be a 1-D dataset, got {d.shown_shape}")
                continue
            if not np.issubdtype(d.dtype, np.floating):
                out.append(f"{where}/{key} must be float64, got {d.dtype}")
            lengths[key] = d.shape[0] if d.shape else 0   # a 1-D dataset: always a 1-tuple
        if len(set(lengths.values())) > 1:
            out.append(f"{where} datasets differ in length: "
                       + ", ".join(f"{k}={v}" for k, v in lengths.items())
                       + " (all must have the same N)")
        n = next(iter(lengths.values())) if lengths else None
        for key, shape in (("wrench", (n, 6)), ("sync", (n,))):
            if key in members and n is not None:
                d = members[key]
                if not d.is_dataset or d.shape != shape:
                    out.append(f"{where}/{key} must have shape {shape}, got {d.shown_shape}")
                elif d.dtype is None or d.dtype.kind not in "iuf":
                    out.append(f"{where}/{key} must be numeric, got {d.dtype}")
        for key in OPTIONAL_SIGNALS:
            m = members.get(key)
            if m is not None and m.is_dataset and np.issubdtype(m.dtype, np.integer) and \
                    not has_attr(m.id, "scale"):
                out.append(f"{where}/{key} holds integer counts without a 'scale' attribute "
                           "(value = offset + scale * count)")


def _group_names(gid) -> list[str]:
    """The names in the low-level group ``gid``, as iterating an h5py ``Group`` gives them."""
    return list(_h5py().Group(gid))


def _validate_trial_attrs(a, where: str, out: list[str], fatal_only: bool,
                          warn: list[str]) -> None:
    """Check a trial's attributes ``a`` (a mapping: the group's, read once)."""
    found = trial_attr_findings(a, where)
    out += found.problems
    warn += found.warnings
    status = _as_str(a.get("status", "completed"))
    if fatal_only:
        return
    if status == "completed" and _as_str(a.get("abort_reason", "")):
        out.append(f"{where} is completed but has a non-empty abort_reason")
    if status == "aborted" and "abort_reason" in a and not _as_str(a["abort_reason"]):
        out.append(f"{where} is aborted but abort_reason is empty (say why)")
    if "started_utc" in a and _as_str(a["started_utc"]) and \
            not _is_utc(_as_str(a["started_utc"])):
        out.append(f"{where} started_utc {_as_str(a['started_utc'])!r} is not ISO 8601 UTC")


#: The members of a trial the structural checks open.
_CHECKED = frozenset((*TRIAL_DATASETS, "wrench", "sync", *OPTIONAL_SIGNALS))

#: The attributes of an event the checks and the reader look at.
EVENT_ATTRS = ("utc", "kind", "detail")


def _validate_events(g, warn: list[str], snap: AttrSnapshot | None = None) -> None:
    seen: dict[str, dict] = {}
    for key in g:
        eid = open_group(g.id, key)
        if eid is None:
            continue
        a = read_attrs(eid, only=EVENT_ATTRS)
        found = seen[key] = {name: a[name] for name in EVENT_ATTRS if name in a}
        for name, value in found.items():
            p = printable_problem(f"/events/{key}", name, value)
            if p:
                warn.append(p)
    if snap is not None:
        snap.events = seen


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


def _data_problems(f, warnings: list[str] | None = None) -> list[str]:
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
                                        n_max=None, warnings=warnings)
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
                                            n_max=n_max, warnings=warnings)
    return out
