"""Read, write and validate session files (``shared/spec/session-file-v1.md``).

One HDF5 file holds one session. This module is the only place that knows the layout: the
rig writes through :class:`SessionWriter`, the analysis reads through :func:`read_session`,
and ``nmsid validate`` calls :func:`validate_session`.

Every write opens the file, changes it and closes it again, so that the file on disk is
complete between writes. Crash recovery (a journal of completed trials) is layered on top
by ``rig.session_log``.

Examples
--------
>>> import tempfile, os, numpy as np
>>> path = os.path.join(tempfile.mkdtemp(), "P01.h5")
>>> w = SessionWriter.create(path, participant="P01")
>>> w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0))
>>> n = 100
>>> name = w.append_trial(Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=np.full(n, 0.5),
...     I_ext_mA=np.full(n, 3.0), I_flex_mA=np.full(n, 3.0), force_N=np.zeros(n)))
>>> name
't001'
>>> read_session(path).trials[0].sE
0.5
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.errors import UserError

FORMAT = "nmsid-session"
FORMAT_VERSION = 1
PARTICIPANT_PATTERN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
TRIAL_NAME_PATTERN = re.compile(r"^t(\d{3,})$")

ROOT_ATTRS = ("format", "format_version", "participant", "created_utc", "software")
CALIBRATION_ATTRS = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")
TRIAL_FLOAT_ATTRS = ("sE", "fs_Hz", "steady_s", "chirp_s", "chirp_f0_Hz", "chirp_f1_Hz",
                     "carrier_Hz")
TRIAL_STR_ATTRS = ("status", "abort_reason", "started_utc")
TRIAL_DATASETS = ("rE", "I_ext_mA", "I_flex_mA", "force_N")
STATUSES = ("completed", "aborted")

GZIP_LEVEL = 4
"""Default deflate level of trial datasets (with the shuffle filter). Measured on the demo
session by ``bench/bench_share.py``: with the float64 chain (before the simulated A/D)
114 MB plain, 73.8 MB at level 1, 73.3 MB at 4, 73.1 MB at 9; with the 16-bit A/D
chain and the wrench as counts 33.6 / 33.3 / 33.1 MB at 1 / 4 / 9, while level 9
writes three to four times slower than 4."""
MIN_SAVING = 0.25
"""A dataset is stored compressed only if deflate saves at least this fraction of it
(checked on its shuffled bytes at level 1). The simulated force_N (a float64 combination
of three A/D channels, full mantissas) saves about 15 %: it stays plain, so reading all
force data costs what it did before."""
CHUNK_SAMPLES = 65536
"""Most samples per chunk: a whole 15 s trial at 2 kHz is one chunk per signal, so reading
a dataset inflates one chunk once."""


OPTIONAL_SIGNALS = ("wrench", "sync")
"""Optional trial datasets. Each is stored as the values (float64, or float32 when every
sample is float32-exact) or, when every sample is an A/D count times a step, as integer
counts (int8/16/32) with attributes ``scale`` and ``offset`` (scalars, or one per column
of ``wrench``): value = offset + scale * count, float64, bit-exact. :func:`read_session`
returns float64 values either way."""


#: Optional trial attributes describing a non-chirp input (written by the rig since the
#: designer, ``nmsid design``, can propose other inputs). ``input_kind``: ``"chirp"`` (the
#: paper's; also assumed when absent) or ``"multisine"``; ``input_json``: the input's
#: parameters as JSON. For a non-chirp input the contract's ``chirp_s``, ``chirp_f0_Hz``,
#: ``chirp_f1_Hz`` are the excitation's length and band.
OPTIONAL_INPUT_ATTRS = ("input_kind", "input_json")


def trial_input(trial: Trial) -> dict[str, Any]:
    """The input a trial used: ``{"kind": ..., ...}`` from its optional attributes.

    A trial without them (every file written before they existed, other labs' files) used
    the paper's chirp, described by the contract's ``chirp_*`` attributes.
    """
    extra = trial.extra_attrs
    kind = _as_str(extra.get("input_kind", "chirp")) or "chirp"
    out: dict[str, Any] = {}
    if "input_json" in extra:
        try:
            parsed = json.loads(_as_str(extra["input_json"]))
            if isinstance(parsed, dict):
                out.update(parsed)
        except json.JSONDecodeError:
            pass
    out.update({"kind": kind})
    out.setdefault("steady_s", float(trial.steady_s))
    out.setdefault("duration_s", float(trial.chirp_s))
    out.setdefault("f0_Hz", float(trial.chirp_f0_Hz))
    out.setdefault("f1_Hz", float(trial.chirp_f1_Hz))
    return out


def software_id() -> str:
    """The writer's name and version, as stored in the ``software`` root attribute."""
    try:
        from importlib.metadata import version
        return f"nmsid {version('nmsid')}"
    except Exception:  # not installed (running from a source tree)
        return "nmsid (source tree)"


def utc_now() -> str:
    """The current time as ISO 8601 UTC with a ``Z`` suffix (second resolution)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


class SessionFileError(UserError):
    """A session file is missing, unreadable or breaks the contract.

    The message names the file and the item, and says what would be valid.
    """

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class SessionExistsError(UserError, FileExistsError):
    """Refused to create a session file where a file already exists (never overwrite)."""

    def __init__(self, path: str | os.PathLike):
        self.path = str(path)
        super().__init__(
            f"{self.path}: a file already exists here; nmsid never overwrites a session "
            "file. Choose another --out path, or resume it with --resume.")


@dataclass
class Calibration:
    """Currents at which each muscle alone produced ``Fmin_N`` / ``Fmax_N``."""

    Iemin_mA: float
    Iemax_mA: float
    Ifmin_mA: float
    Ifmax_mA: float
    Fmin_N: float = 0.5
    Fmax_N: float = 5.0
    ramps: dict[str, np.ndarray] = field(default_factory=dict)
    """Optional datasets stored under ``/calibration`` (e.g. ``ext_I_mA``, ``ext_force_N``)."""

    def problems(self) -> list[str]:
        """Every way these values break the contract (empty when valid)."""
        out = []
        for name in CALIBRATION_ATTRS:
            value = getattr(self, name)
            if not np.isfinite(value):
                out.append(f"/calibration attribute {name} = {value!r} is not a finite number")
        if not (self.Iemax_mA > self.Iemin_mA >= 0):
            out.append(f"/calibration needs Iemax_mA > Iemin_mA >= 0, got Iemin_mA="
                       f"{self.Iemin_mA:g}, Iemax_mA={self.Iemax_mA:g}")
        if not (self.Ifmax_mA > self.Ifmin_mA >= 0):
            out.append(f"/calibration needs Ifmax_mA > Ifmin_mA >= 0, got Ifmin_mA="
                       f"{self.Ifmin_mA:g}, Ifmax_mA={self.Ifmax_mA:g}")
        return out


@dataclass
class Trial:
    """One trial: its settings (attributes) and its sampled signals (datasets)."""

    sE: float
    repeat: int
    fs_Hz: float
    rE: np.ndarray
    I_ext_mA: np.ndarray
    I_flex_mA: np.ndarray
    force_N: np.ndarray
    status: str = "completed"
    abort_reason: str = ""
    steady_s: float = 5.0
    chirp_s: float = 10.0
    chirp_f0_Hz: float = 1.0
    chirp_f1_Hz: float = 10.0
    carrier_Hz: float = 1000.0
    started_utc: str = ""
    wrench: np.ndarray | None = None
    sync: np.ndarray | None = None
    name: str = ""
    """``t001``, ``t002``, ... ; set by the writer and the reader."""
    extra_attrs: dict[str, Any] = field(default_factory=dict)
    """Attributes beyond the contract (e.g. ``index_in_schedule``, ``cumulative_stim_s``)."""

    @property
    def n_samples(self) -> int:
        return int(len(self.force_N))

    @property
    def completed(self) -> bool:
        return self.status == "completed"

    @property
    def t_s(self) -> np.ndarray:
        """Sample times in s after stimulation onset."""
        return np.arange(self.n_samples) / self.fs_Hz


@dataclass
class Event:
    """One entry of the session's event log."""

    utc: str
    kind: str
    detail: str = ""


@dataclass
class Session:
    """Everything a session file holds, as read by :func:`read_session`."""

    path: str
    participant: str
    created_utc: str
    software: str
    calibration: Calibration
    trials: list[Trial]
    events: list[Event] = field(default_factory=list)
    config_json: str = ""
    seed: int | None = None
    backend: str = ""
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def config(self) -> dict:
        """The protocol configuration stored with the session (empty if none)."""
        if not self.config_json:
            return {}
        try:
            return json.loads(self.config_json)
        except json.JSONDecodeError:
            return {}

    def completed_trials(self) -> list[Trial]:
        return [t for t in self.trials if t.completed]

    def sE_levels(self) -> list[float]:
        """The distinct sE values of completed trials, ascending."""
        return sorted({round(float(t.sE), 10) for t in self.completed_trials()})


def _h5py():
    import h5py
    return h5py


def _as_str(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _as_str(value[()])
    return str(value)


def _as_float(value: Any) -> float:
    arr = np.asarray(value)
    if arr.size != 1:
        raise TypeError("not a scalar")
    return float(arr.reshape(()))


class SessionWriter:
    """Write a session file incrementally; every call leaves a complete file on disk.

    Use :meth:`create` for a new session (refuses an existing path) and :meth:`open`
    to continue one (``--resume``).
    """

    def __init__(self, path: str | os.PathLike, *, gzip_level: int | None = GZIP_LEVEL,
                 store_counts: bool = True):
        self.path = Path(path)
        if gzip_level is not None and gzip_level not in range(1, 10):
            raise ValueError(f"gzip_level {gzip_level!r} is not valid: use 1 ... 9, or None "
                             "for uncompressed datasets")
        self.gzip_level = gzip_level
        """Deflate level of new datasets (with shuffle), or None to store them plain."""
        self.store_counts = bool(store_counts)
        """Store an optional signal on an exact grid as integer counts + ``scale`` /
        ``offset`` (see :data:`OPTIONAL_SIGNALS`); False: always as floats."""

    # -- creation -----------------------------------------------------------------
    @classmethod
    def create(cls, path: str | os.PathLike, participant: str, *,
               created_utc: str | None = None, software: str | None = None,
               config_json: str | None = None, seed: int | None = None,
               backend: str | None = None, extra_attrs: dict | None = None,
               gzip_level: int | None = GZIP_LEVEL,
               store_counts: bool = True) -> SessionWriter:
        """Create a new session file with its root attributes and empty groups.

        Raises
        ------
        SessionExistsError
            If anything exists at ``path``.
        ValueError
            If ``participant`` is not ``[A-Za-z0-9_-]{1,64}``.
        """
        path = Path(path)
        if not PARTICIPANT_PATTERN.match(participant or ""):
            raise ValueError(
                f"participant code {participant!r} is not valid: use 1 to 64 letters, "
                "digits, '_' or '-' (a code, never a name)")
        if path.exists():
            raise SessionExistsError(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        h5py = _h5py()
        str_dt = h5py.string_dtype("utf-8")
        # mode "x": fails if the file appears between the check and the open.
        try:
            f = h5py.File(path, "x")
        except (FileExistsError, OSError) as exc:
            if path.exists():
                raise SessionExistsError(path) from exc
            raise
        with f:
            f.attrs.create("format", FORMAT, dtype=str_dt)
            f.attrs["format_version"] = np.int64(FORMAT_VERSION)
            f.attrs.create("participant", participant, dtype=str_dt)
            f.attrs.create("created_utc", created_utc or utc_now(), dtype=str_dt)
            f.attrs.create("software", software or software_id(), dtype=str_dt)
            if config_json is not None:
                f.attrs.create("config_json", config_json, dtype=str_dt)
            if seed is not None:
                f.attrs["seed"] = np.int64(seed)
            if backend is not None:
                f.attrs.create("backend", backend, dtype=str_dt)
            for key, value in (extra_attrs or {}).items():
                _set_attr(f.attrs, key, value)
            f.create_group("calibration")
            f.create_group("trials")
            f.create_group("events")
        return cls(path, gzip_level=gzip_level, store_counts=store_counts)

    @classmethod
    def open(cls, path: str | os.PathLike, *, gzip_level: int | None = GZIP_LEVEL,
             store_counts: bool = True) -> SessionWriter:
        """Continue writing an existing session file (checks that it is one)."""
        path = Path(path)
        if not path.exists():
            raise SessionFileError(path, "no such file")
        with _open_read(path) as f:
            if _as_str(f.attrs.get("format", "")) != FORMAT:
                raise SessionFileError(path, "is not an nmsid session file "
                                             f"(root attribute format != {FORMAT!r})")
        return cls(path, gzip_level=gzip_level, store_counts=store_counts)

    # -- writing ------------------------------------------------------------------
    def write_calibration(self, cal: Calibration) -> None:
        """Store the calibration (attributes and optional ramp datasets)."""
        problems = cal.problems()
        if problems:
            raise ValueError(f"{self.path}: refusing to write calibration: " + "; ".join(problems))
        with _h5py().File(self.path, "a") as f:
            g = f.require_group("calibration")
            for name in CALIBRATION_ATTRS:
                g.attrs[name] = float(getattr(cal, name))
            for name, data in cal.ramps.items():
                if name in g:
                    del g[name]
                self._create_dataset(g, name, np.asarray(data, dtype=float))

    def next_trial_name(self) -> str:
        with _open_read(self.path) as f:
            n = len([k for k in f.get("trials", {}) if TRIAL_NAME_PATTERN.match(k)])
        return f"t{n + 1:03d}"

    def append_trial(self, trial: Trial) -> str:
        """Append one trial as the next ``tNNN`` group and return its name."""
        _check_trial(trial, self.path)
        h5py = _h5py()
        str_dt = h5py.string_dtype("utf-8")
        with h5py.File(self.path, "a") as f:
            trials = f.require_group("trials")
            n = len([k for k in trials if TRIAL_NAME_PATTERN.match(k)])
            name = f"t{n + 1:03d}"
            g = trials.create_group(name)
            for key in TRIAL_FLOAT_ATTRS:
                g.attrs[key] = float(getattr(trial, key))
            g.attrs["repeat"] = np.int64(trial.repeat)
            for key in TRIAL_STR_ATTRS:
                g.attrs.create(key, getattr(trial, key) or "", dtype=str_dt)
            for key, value in trial.extra_attrs.items():
                _set_attr(g.attrs, key, value)
            for key in TRIAL_DATASETS:
                self._create_dataset(g, key, np.asarray(getattr(trial, key), dtype=np.float64))
            for key in OPTIONAL_SIGNALS:
                values = getattr(trial, key)
                if values is not None:
                    self._create_signal(g, key, values)
            f.flush()
        trial.name = name
        return name

    def _create_dataset(self, group, name: str, data: np.ndarray):
        """Create ``group[name]`` chunked with shuffle + deflate (lossless, transparent to
        every HDF5 reader), or plain when ``gzip_level`` is None, ``data`` is empty or
        deflate would save less than :data:`MIN_SAVING` of it."""
        if self.gzip_level is None or data.size == 0 or not _deflates(data):
            return group.create_dataset(name, data=data)
        n = data.shape[0]
        chunks = (min(n, CHUNK_SAMPLES),) + (1,) * (data.ndim - 1)
        return group.create_dataset(name, data=data, chunks=chunks, shuffle=True,
                                    compression="gzip", compression_opts=self.gzip_level)

    def _create_signal(self, group, name: str, values) -> None:
        """An optional signal (``wrench``, ``sync``) as integer counts with ``scale`` /
        ``offset`` attributes when every sample is ``offset + scale * count`` bit for bit
        (A/D readings), else float32 when float32-exact, else float64."""
        grid = _as_counts(values) if self.store_counts else None
        if grid is None:
            self._create_dataset(group, name, _narrowest_exact(values))
            return
        counts, scale, offset = grid
        d = self._create_dataset(group, name, counts)
        d.attrs["scale"] = scale
        d.attrs["offset"] = offset

    def append_events(self, events: list[Event]) -> None:
        """Append events to ``/events`` (one sub-group per event, ``e0001``, ...)."""
        if not events:
            return
        h5py = _h5py()
        str_dt = h5py.string_dtype("utf-8")
        with h5py.File(self.path, "a") as f:
            g = f.require_group("events")
            n = len(g)
            for i, ev in enumerate(events):
                e = g.create_group(f"e{n + i + 1:05d}")
                e.attrs.create("utc", ev.utc, dtype=str_dt)
                e.attrs.create("kind", ev.kind, dtype=str_dt)
                e.attrs.create("detail", ev.detail, dtype=str_dt)

    def set_root_attrs(self, **attrs: Any) -> None:
        """Add or update optional root attributes (never the required ones)."""
        with _h5py().File(self.path, "a") as f:
            for key, value in attrs.items():
                if key in ROOT_ATTRS:
                    raise ValueError(f"{self.path}: root attribute {key!r} is fixed at creation")
                _set_attr(f.attrs, key, value)


def _set_attr(attrs, key: str, value: Any) -> None:
    if isinstance(value, str):
        attrs.create(key, value, dtype=_h5py().string_dtype("utf-8"))
    elif isinstance(value, (dict, list)):
        attrs.create(key, json.dumps(value), dtype=_h5py().string_dtype("utf-8"))
    else:
        attrs[key] = value


def _deflates(data: np.ndarray) -> bool:
    """True if shuffle + deflate saves at least :data:`MIN_SAVING` of ``data``, judged
    the way it is chunked (each column of a 2-D dataset on its own)."""
    raw = np.asarray(data)
    columns = [raw] if raw.ndim == 1 else [raw[:, k] for k in range(raw.shape[1])]
    packed = 0
    for col in columns:
        col = np.ascontiguousarray(col)
        shuffled = col.view(np.uint8).reshape(-1, col.dtype.itemsize).T.tobytes()
        packed += len(zlib.compress(shuffled, 1))
    return packed <= (1.0 - MIN_SAVING) * raw.nbytes


def counts_to_values(counts: np.ndarray, scale, offset) -> np.ndarray:
    """float64 ``offset + scale * counts`` (``scale``, ``offset``: scalars, or one per
    column of a 2-D dataset): how a reader turns a stored count dataset into values."""
    out = np.asarray(counts).astype(np.float64)
    out *= np.asarray(scale, dtype=np.float64)
    out += np.asarray(offset, dtype=np.float64)
    return out


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


_MAX_SUBSTEPS = 4096
"""A grid is found when its step is at least 1/4096 of the smallest gap between values."""


def _column_step(col: np.ndarray) -> float | None:
    """The step ``q`` with ``col == q * k`` bit for bit for integers ``k`` (|k| < 2**31),
    or None. Candidates: ``x / k`` of the largest samples and their neighbouring floats
    (``fl(q * k)`` is correctly rounded, so the true step is within an ulp or two)."""
    nz = np.unique(np.abs(col[col != 0.0]))
    if nz.size == 0:
        return None
    diffs = np.concatenate([nz[:1], np.diff(nz)])
    step0 = float(diffs.min())
    if not step0 > 0 or nz[-1] / step0 >= 2 ** 31:
        return None
    # sparse codes: the smallest gap may be several steps; the step divides every gap.
    # A gap between floats is off by up to ~2 ulps of its upper end, so the test that
    # ``m * gap / step0`` is whole allows for that error (and step0's own) times m.
    substeps = [1]
    pick = slice(None, None, max(1, diffs.size // 64))
    gaps, ups = diffs[pick][:64], nz[pick][:64]
    ratios = gaps / step0
    if ratios.max() * _MAX_SUBSTEPS < 2 ** 40:
        eps = np.finfo(float).eps
        err0 = 2 * eps * nz[int(np.argmin(diffs))]
        ratio_err = (2 * eps * ups + ratios * err0) / step0
        m = np.arange(1, _MAX_SUBSTEPS + 1)[:, None]
        ok = np.flatnonzero((np.abs(m * ratios - np.rint(m * ratios))
                             < 1e-4 + 2 * m * ratio_err).all(axis=1))
        if ok.size == 0:
            return None
        substeps = [int(k) + 1 for k in ok[:8]]
    for sub in substeps:
        q = _exact_step_near(col, nz, step0 / sub)
        if q is not None:
            return q
    return None


def _exact_step_near(col: np.ndarray, nz: np.ndarray, step0: float) -> float | None:
    """The float ``q`` within a few ulps of ``x / round(x / step0)`` (x: a large, middle
    and small sample) for which ``col == q * round(col / q)`` bit for bit, or None."""
    tried = set()
    for x in (nz[-1], nz[nz.size // 2], nz[0]):
        k = float(np.rint(x / step0))
        if k < 1:
            continue
        q = x / k
        for cand in (q, *np.nextafter(q, [np.inf, 0.0]),
                     *np.nextafter(np.nextafter(q, [np.inf, 0.0]), [np.inf, 0.0])):
            cand = float(cand)
            if cand in tried or not cand > 0:
                continue
            tried.add(cand)
            counts = np.rint(col / cand)
            if np.abs(counts).max() < 2 ** 31 and _same_bits(counts * cand, col):
                return cand
    return None


def _as_counts(values) -> tuple[np.ndarray, Any, Any] | None:
    """``(counts, scale, offset)`` if every sample of ``values`` (1-D, or 2-D column by
    column) is ``offset + scale * count`` bit for bit as :func:`counts_to_values`
    rebuilds it, with the counts as int8/int16/int32; else None.

    A/D readings (``code * LSB``, the simulated chain's wrench, a sync line at 0 / 5 V)
    pass; float noise does not. The writer detects grids through zero (``offset`` 0);
    readers honour any ``offset``.
    """
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0 or arr.ndim not in (1, 2) or not np.isfinite(arr).all():
        return None
    cols = [arr] if arr.ndim == 1 else [arr[:, k] for k in range(arr.shape[1])]
    scales = []
    for col in cols:
        if not col.any():
            scales.append(1.0)
            continue
        q = _column_step(col)
        if q is None:
            return None
        scales.append(q)
    scale = np.array(scales) if arr.ndim == 2 else np.float64(scales[0])
    counts = np.rint(arr / scale)
    dtype = next(dt for dt in (np.int8, np.int16, np.int32)
                 if np.iinfo(dt).min <= counts.min() and counts.max() <= np.iinfo(dt).max)
    counts = counts.astype(dtype)
    offset = np.zeros_like(scale)
    if not _same_bits(counts_to_values(counts, scale, offset), arr):
        return None
    return counts, scale, offset


def _narrowest_exact(values) -> np.ndarray:
    """``values`` as float32 if every sample survives the round trip bit for bit (a
    measurement that was float32 or A/D counts to begin with), else as float64.

    Only the optional datasets (``wrench``, ``sync``) are narrowed; the contract fixes
    the required ones at float64.
    """
    arr = np.asarray(values)
    as64 = arr.astype(np.float64)
    as32 = as64.astype(np.float32)
    if np.array_equal(as32.astype(np.float64), as64, equal_nan=True):
        return as32
    return as64


def _check_trial(trial: Trial, path) -> None:
    n = len(trial.force_N)
    for key in TRIAL_DATASETS:
        arr = np.asarray(getattr(trial, key))
        if arr.ndim != 1 or len(arr) != n:
            raise ValueError(f"{path}: trial dataset {key} must be 1-D with {n} samples "
                             f"(as force_N), got shape {arr.shape}")
    if trial.wrench is not None and np.asarray(trial.wrench).shape != (n, 6):
        raise ValueError(f"{path}: trial dataset wrench must have shape ({n}, 6), "
                         f"got {np.asarray(trial.wrench).shape}")
    if trial.status not in STATUSES:
        raise ValueError(f"{path}: trial status {trial.status!r} is not one of {STATUSES}")
    if not (trial.fs_Hz > 0):
        raise ValueError(f"{path}: trial fs_Hz must be > 0, got {trial.fs_Hz!r}")


_DAMAGE_ERRORS = (KeyError, OSError, RuntimeError, ValueError)
"""What h5py raises when a file cut short by a crash is read past its end."""


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
        problems = _problems(f, fatal_only=True)
        if problems:
            raise SessionFileError(path, problems[0] + (
                f" (and {len(problems) - 1} more problem(s); run `nmsid validate {path}`)"
                if len(problems) > 1 else ""))
        wanted = (set(TRIAL_DATASETS) | {"wrench", "sync"}) if datasets is None else set(datasets)
        if not load_data:
            wanted = set()
        a = f.attrs
        cal_g = f["calibration"]
        cal = Calibration(**{k: _as_float(cal_g.attrs[k]) for k in CALIBRATION_ATTRS},
                          ramps={k: np.asarray(cal_g[k][()]) for k in cal_g
                                 if isinstance(cal_g[k], _h5py().Dataset)} if load_data else {})
        try:
            trials = [_read_trial(f["trials"][name], name, wanted)
                      for name in _trial_names(f["trials"])]
            events = _read_events(f["events"]) if "events" in f else []
        except _DAMAGE_ERRORS as exc:
            raise SessionFileError(path, f"damaged: data cannot be read ({type(exc).__name__}:"
                                         f" {exc}); if it was being written when a program "
                                         "stopped, run `nmsid recover` on it") from None
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
        )


def _trial_names(group) -> list[str]:
    names = [k for k in group if TRIAL_NAME_PATTERN.match(k)]
    return sorted(names, key=lambda k: int(TRIAL_NAME_PATTERN.match(k).group(1)))


def _read_trial(g, name: str, wanted: set[str]) -> Trial:
    a = g.attrs
    kw: dict[str, Any] = {k: _as_float(a[k]) for k in TRIAL_FLOAT_ATTRS}
    kw.update({k: _as_str(a[k]) for k in TRIAL_STR_ATTRS})
    kw["repeat"] = int(np.asarray(a["repeat"]))
    for key in TRIAL_DATASETS:
        kw[key] = (np.asarray(g[key][()], dtype=np.float64) if key in wanted
                   else np.empty(0))
    for key in OPTIONAL_SIGNALS:
        kw[key] = _read_signal(g[key]) if key in wanted and key in g else None
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


def _read_events(g) -> list[Event]:
    out = []
    for key in sorted(g):
        e = g[key]
        if isinstance(e, _h5py().Group):
            out.append(Event(_as_str(e.attrs.get("utc", "")), _as_str(e.attrs.get("kind", "")),
                             _as_str(e.attrs.get("detail", ""))))
    return out


# -- validation -------------------------------------------------------------------
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
