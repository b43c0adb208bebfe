"""Reading session files: :func:`read_session`."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.protocols.session_checks import max_current_mA, value_problem, value_warning
from nmsid.protocols.session_codec import counts_to_values
from nmsid.protocols.session_h5 import (
    Member,
    float64_buffers,
    open_group,
    open_member,
    read_float64,
)
from nmsid.protocols.session_lock import live_writer
from nmsid.protocols.session_model import (
    _DAMAGE_ERRORS,
    CALIBRATION_ATTRS,
    OPTIONAL_SIGNALS,
    ROOT_ATTRS,
    TRIAL_DATASETS,
    TRIAL_FLOAT_ATTRS,
    TRIAL_STR_ATTRS,
    Calibration,
    Event,
    Session,
    SessionFileError,
    Trial,
    _as_float,
    _as_str,
    _h5py,
    _trial_names,
)
from nmsid.protocols.session_validator import EVENT_ATTRS, AttrSnapshot, _problems

log = logging.getLogger(__name__)


class _open_read:
    """``with _open_read(path) as f``: open read-only, turning h5py errors into a
    :class:`SessionFileError` that names the file."""

    def __init__(self, path):
        self.path = Path(path)
        self.f = None

    def __enter__(self):
        if not self.path.exists():
            raise SessionFileError(self.path, "no such file")
        try:
            self.f = _h5py().File(self.path, "r")
        except OSError as exc:
            raise SessionFileError(
                self.path, f"cannot be opened as HDF5 ({exc}); if a session was running "
                "when the computer or program stopped, run `nmsid recover` on it") from None
        return self.f

    def __exit__(self, *exc):
        if self.f is not None:
            self.f.close()
        return False


# -- reading ----------------------------------------------------------------------
def read_session(path: str | os.PathLike, *, load_data: bool = True,
                 datasets: tuple[str, ...] | None = None) -> Session:
    """Read a whole session file.

    Parameters
    ----------
    path : path-like
        The ``.h5`` file.
    load_data : bool
        If False, trial datasets are left empty (fast listing of attributes).
    datasets : tuple of str, optional
        Read only these trial datasets (e.g. ``("rE", "force_N")``); the others are left
        empty (``wrench`` / ``sync`` None). Default: all.

    Raises
    ------
    SessionFileError
        If the file is missing, not HDF5, or lacks a required item; the message names
        the file and the item.
    """
    path = Path(path)
    with _open_read(path) as f:
        try:
            warnings: list[str] = []
            snap = AttrSnapshot()   # the checks read each attribute once; reused below
            problems = _problems(f, fatal_only=True, warnings=warnings, snapshot=snap)
        except _DAMAGE_ERRORS as exc:
            raise SessionFileError(path, f"damaged: an item cannot be read ({type(exc).__name__}"
                                         f": {exc}); if it was being written when a program "
                                         "stopped, run `nmsid recover` on it") from None
        if problems:
            raise SessionFileError(path, problems[0] + (
                f" (and {len(problems) - 1} more problem(s); run `nmsid validate {path}`)"
                if len(problems) > 1 else ""))
        wanted = (set(TRIAL_DATASETS) | {"wrench", "sync"}) if datasets is None else set(datasets)
        if not load_data:
            wanted = set()
        a = snap.of(f)
        cal_g = f["calibration"]
        try:
            cal_a = snap.of(cal_g)
            cal = Calibration(**{k: _as_float(cal_a[k]) for k in CALIBRATION_ATTRS},
                              ramps={k: np.asarray(cal_g[k][()]) for k in cal_g
                                     if isinstance(cal_g[k], _h5py().Dataset)}
                              if load_data else {})
            trials_g = f["trials"]
            trials = []
            names = _trial_names(trials_g)
            buffers = float64_buffers([m for n in names for k, m in
                                       snap.members.get(n, {}).items()
                                       if k in wanted and k in TRIAL_DATASETS])
            for name in names:
                members = snap.members.get(name)
                attrs = snap.cached(f"/trials/{name}")
                if members is None or attrs is None:  # the checks open every trial
                    g = trials_g[name]
                    trials.append(_read_trial(g, name, wanted, snap.of(g)))
                else:
                    trials.append(_read_trial(trials_g, name, wanted, attrs, members,
                                              buffers))
            events = (_read_events(f["events"], snap.events) if "events" in f else [])
        except _DAMAGE_ERRORS as exc:
            raise SessionFileError(path, f"damaged: data cannot be read ({type(exc).__name__}:"
                                         f" {exc}); if it was being written when a program "
                                         "stopped, run `nmsid recover` on it") from None
        max_mA = max_current_mA(_as_str(a.get("config_json", "")))
        for t in trials:
            for key in (*TRIAL_DATASETS, *OPTIONAL_SIGNALS):
                values = getattr(t, key)
                problem = None if values is None else value_problem(key, values)
                if problem:
                    raise SessionFileError(path, f"/trials/{t.name}/{key} {problem}")
                warning = None if values is None else value_warning(key, values, max_mA)
                if warning:
                    warnings.append(f"/trials/{t.name}/{key} {warning}")
        for w in warnings[:5]:  # allowed by the contract, implausible: said, then analysed
            log.warning("%s: %s", path, w)
        if len(warnings) > 5:
            log.warning("%s: and %d more warning(s); run `nmsid validate %s`", path,
                        len(warnings) - 5, path)
        writer = live_writer(path)
        if writer is not None and writer.pid != os.getpid():
            log.warning("%s: live session: written now by %s; read %d trial(s) so far",
                        path, writer.describe(), len(trials))
        known = set(ROOT_ATTRS) | {"config_json", "seed", "backend"}
        seed = a.get("seed")
        return Session(
            path=str(path),
            participant=_as_str(a["participant"]),
            created_utc=_as_str(a["created_utc"]),
            software=_as_str(a["software"]),
            calibration=cal,
            trials=trials,
            events=events,
            config_json=_as_str(a.get("config_json", "")),
            seed=int(np.asarray(seed)) if seed is not None else None,
            backend=_as_str(a.get("backend", "")),
            attrs={k: a[k] for k in a if k not in known},
            warnings=warnings,
        )


def _read_trial(g, name: str, wanted: set[str], attrs: dict | None = None,
                members: dict[str, Member] | None = None,
                buffers: dict[int, np.ndarray] | None = None) -> Trial:
    """One trial; ``attrs``: the group's attributes when read already; ``members``: its
    datasets opened already by the checks (then ``g`` is the ``/trials`` group and the
    required datasets are read through them, into the arrays of ``buffers`` where given,
    see :func:`nmsid.protocols.session_h5.float64_buffers`)."""
    a = attrs if attrs is not None else g.attrs
    tid = None
    if members is not None:
        tid = open_group(g.id, name)
        if tid is None:   # the checks found a group here, in this same open file
            raise KeyError(f"/trials/{name} is not a group")
        if any(k in wanted and k in members for k in OPTIONAL_SIGNALS):
            g = g[name]   # the optional signals are read through h5py (counts, scales)
    kw: dict[str, Any] = {k: _as_float(a[k]) for k in TRIAL_FLOAT_ATTRS}
    kw.update({k: _as_str(a[k]) for k in TRIAL_STR_ATTRS})
    kw["repeat"] = int(np.asarray(a["repeat"]))
    for key in TRIAL_DATASETS:
        if key not in wanted:
            kw[key] = np.empty(0)
        elif members is not None:
            m = open_member(tid, key)
            kw[key] = read_float64(m, (buffers or {}).get(id(members[key])))
        else:
            kw[key] = np.asarray(g[key][()], dtype=np.float64)
    for key in OPTIONAL_SIGNALS:
        present = key in members if members is not None else key in g
        kw[key] = _read_signal(g[key]) if key in wanted and present else None
    known = set(TRIAL_FLOAT_ATTRS) | set(TRIAL_STR_ATTRS) | {"repeat"}
    extra = {k: (_as_str(a[k]) if isinstance(a[k], (str, bytes)) else a[k])
             for k in a if k not in known}
    return Trial(name=name, extra_attrs=extra, **kw)


def _read_signal(d) -> np.ndarray:
    """An optional signal as float64: stored counts (an integer dataset with ``scale`` /
    ``offset``) rebuilt by :func:`counts_to_values`, float32 / float64 widened."""
    data = d[()]
    if np.issubdtype(d.dtype, np.integer) and "scale" in d.attrs:
        return counts_to_values(data, d.attrs["scale"], d.attrs.get("offset", 0.0))
    return np.asarray(data, dtype=np.float64)


def _read_events(g, seen: dict[str, dict] | None = None) -> list[Event]:
    """The events in name order; ``seen``: each event group's attributes (those of
    ``EVENT_ATTRS`` present) as the checks read them, else read here."""
    if seen is None:
        seen = {}
        for key in g:
            e = g[key]
            if isinstance(e, _h5py().Group):
                seen[key] = {n: e.attrs[n] for n in EVENT_ATTRS if n in e.attrs}
    return [Event(_as_str(a.get("utc", "")), _as_str(a.get("kind", "")),
                  _as_str(a.get("detail", ""))) for key, a in sorted(seen.items())]


