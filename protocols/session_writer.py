"""Writing session files: :class:`SessionWriter`."""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.protocols.session_checks import trial_attr_findings, value_problem
from nmsid.protocols.session_codec import _as_counts, _deflates, _narrowest_exact, _set_attr
from nmsid.protocols.session_model import (
    CALIBRATION_ATTRS,
    CHUNK_SAMPLES,
    FORMAT,
    FORMAT_VERSION,
    GZIP_LEVEL,
    OPTIONAL_SIGNALS,
    PARTICIPANT_PATTERN,
    ROOT_ATTRS,
    TRIAL_DATASETS,
    TRIAL_FLOAT_ATTRS,
    TRIAL_NAME_PATTERN,
    TRIAL_STR_ATTRS,
    Calibration,
    Event,
    SessionExistsError,
    SessionFileError,
    Trial,
    _as_str,
    _h5py,
    software_id,
    utc_now,
)
from nmsid.protocols.session_publish import publish_image
from nmsid.protocols.session_reader import _open_read


class SessionWriter:
    """Write a session file incrementally; every call publishes a complete new version,
    or, while :attr:`deferred`, changes the in-memory image until :meth:`publish`.

    The writer keeps the file's HDF5 image in memory, changes it there and publishes the
    new image by temp file + fsync + atomic rename (:mod:`nmsid.protocols.session_publish`): it
    never opens the published file for writing, so readers that have it open are never
    disturbed (nor disturb it), and a failed write (a full disk) leaves the published
    version as it was. Every dataset carries a Fletcher-32 checksum (HDF5 filter), which
    every read verifies.

    Use :meth:`create` for a new session (refuses an existing path) and :meth:`open`
    to continue one (``--resume``). One writer per file: the rig takes the session's lock
    (:mod:`nmsid.protocols.session_lock`) before it writes.
    """

    def __init__(self, path: str | os.PathLike, *, gzip_level: int | None = GZIP_LEVEL,
                 store_counts: bool = True, image: bytes | None = None):
        self.path = Path(path)
        if gzip_level is not None and gzip_level not in range(1, 10):
            raise SessionFileError(self.path, f"gzip_level {gzip_level!r} is not valid: use "
                                              "1 ... 9, or None for uncompressed datasets")
        self.gzip_level = gzip_level
        """Deflate level of new datasets (with shuffle), or None to store them plain."""
        self.store_counts = bool(store_counts)
        """Store an optional signal on an exact grid as integer counts + ``scale`` /
        ``offset`` (see :data:`OPTIONAL_SIGNALS`); False: always as floats."""
        self._image = image
        """The published file's bytes (read once, then kept in step with each write)."""
        self.deferred = False
        """True: writes change the in-memory image only, until :meth:`publish` (a
        recorded session publishes at its end; recovery builds a whole file this way and
        publishes it once)."""
        self.unpublished = False
        """True when the in-memory image holds changes not yet published."""
        self._held: tuple[io.BytesIO, Any] | None = None
        """(buffer, open h5py file) of the deferred image, kept open between edits."""

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
        SessionFileError
            If ``participant`` is not ``[A-Za-z0-9_-]{1,64}``.
        DiskFullError
            If the folder has no room for the file.
        """
        path = Path(path)
        if os.path.lexists(path):
            raise SessionExistsError(path)
        image = cls.new_image(path, participant, created_utc=created_utc, software=software,
                              config_json=config_json, seed=seed, backend=backend,
                              extra_attrs=extra_attrs)
        path.parent.mkdir(parents=True, exist_ok=True)
        publish_image(path, image, exclusive=True, doing="creating the session file")
        return cls(path, gzip_level=gzip_level, store_counts=store_counts, image=image)

    @staticmethod
    def new_image(path: str | os.PathLike, participant: str, *,
                  created_utc: str | None = None, software: str | None = None,
                  config_json: str | None = None, seed: int | None = None,
                  backend: str | None = None, extra_attrs: dict | None = None) -> bytes:
        """The bytes of a new session file (root attributes, empty groups); ``path``
        only names the file in errors. :meth:`create` publishes it."""
        if not PARTICIPANT_PATTERN.match(participant or ""):
            raise SessionFileError(
                path, f"participant code {participant!r} is not valid: use 1 to 64 letters, "
                      "digits, '_' or '-' (a code, never a name)")
        check_seed(path, seed)
        h5py = _h5py()
        str_dt = h5py.string_dtype("utf-8")
        bio = io.BytesIO()
        with h5py.File(bio, "w") as f:
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
        return bio.getvalue()

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

    # -- the in-memory image --------------------------------------------------------

    def _load(self) -> bytes:
        """The published image (read once from the file)."""
        if self._image is None:
            try:
                self._image = self.path.read_bytes()
            except OSError as exc:
                raise SessionFileError(self.path, f"cannot be read ({exc.strerror or exc})") \
                    from None
        return self._image

    @contextmanager
    def _edit(self, doing: str):
        """``with self._edit(...) as f``: change the file in memory, then publish it (not
        if the body raises). While :attr:`deferred`, the in-memory file stays open between
        edits, so an edit costs what it adds, not the size of the file."""
        if self.deferred:
            yield self._open_held()
            self.unpublished = True
            return
        bio = io.BytesIO(self._load())
        with _h5py().File(bio, "a") as f:
            yield f
        image = bio.getvalue()
        publish_image(self.path, image, doing=doing)
        self._image = image
        self.unpublished = False

    def _open_held(self):
        if self._held is None:
            bio = io.BytesIO(self._load())
            self._image = None  # the held file is the image now (no second copy)
            self._held = (bio, _h5py().File(bio, "a"))
        return self._held[1]

    def image(self) -> bytes:
        """The file's bytes as they would be published now."""
        if self._held is not None:
            self._held[1].flush()  # HDF5 writes its metadata: the image is a valid file
            return self._held[0].getvalue()
        return self._load()

    def publish(self, doing: str = "writing it", *,
                delays_s: tuple[float, ...] | None = None) -> None:
        """Publish the in-memory image as the file (after deferred writes).

        Raises what :func:`~nmsid.protocols.session_publish.publish_image` raises
        (``FileHeldError`` on Windows while a reader holds the file); the in-memory image
        is kept, so a later call can publish it."""
        if self._held is not None:
            self._held[1].flush()
            publish_image(self.path, self._held[0].getvalue(), doing=doing,
                          delays_s=delays_s)
        else:
            publish_image(self.path, self._load(), doing=doing, delays_s=delays_s)
        self.unpublished = False

    def close(self) -> None:
        """Drop the in-memory image (unpublished changes are lost: publish first); a later
        write reads the published file again. Frees the memory of a finished session."""
        if self._held is not None:
            _, f = self._held
            self._held = None
            f.close()
        self._image = None

    # -- writing ------------------------------------------------------------------
    def write_calibration(self, cal: Calibration, events: Sequence[Event] = ()) -> None:
        """Store the calibration (attributes and optional ramp datasets) and ``events``."""
        problems = cal.problems()
        if problems:
            raise SessionFileError(self.path, "refusing to write calibration: "
                                   + "; ".join(problems))
        with self._edit("writing the calibration") as f:
            g = f.require_group("calibration")
            for name in CALIBRATION_ATTRS:
                g.attrs[name] = float(getattr(cal, name))
            for name, data in cal.ramps.items():
                if name in g:
                    del g[name]
                self._create_dataset(g, name, np.asarray(data, dtype=float))
            _add_events(f, events)

    def append_trial(self, trial: Trial, events: Sequence[Event] = ()) -> str:
        """Append one trial as the next ``tNNN`` group (and ``events``, in the same new
        version of the file); return the trial's name."""
        return self.append_trials([trial], events)[-1]

    def append_trials(self, trials: list[Trial], events: Sequence[Event] = ()) -> list[str]:
        """Append trials (and events) in one new version of the file; return their names."""
        for trial in trials:
            _check_trial(trial, self.path)
        names: list[str] = []
        if not trials and not events:
            return names
        what = (f"writing trial sE {trials[0].sE:g} repeat {trials[0].repeat}"
                if len(trials) == 1 else f"writing {len(trials)} trials")
        with self._edit(what) as f:
            for trial in trials:
                names.append(self._add_trial(f, trial))
            _add_events(f, events)
        for trial, name in zip(trials, names, strict=True):
            trial.name = name
        return names

    def _add_trial(self, f, trial: Trial) -> str:
        str_dt = _h5py().string_dtype("utf-8")
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
        return name

    def _create_dataset(self, group, name: str, data: np.ndarray):
        """Create ``group[name]`` chunked with a Fletcher-32 checksum, plus shuffle +
        deflate (lossless, transparent to every HDF5 reader) unless ``gzip_level`` is
        None, ``data`` is empty or deflate would save less than :data:`MIN_SAVING`."""
        n = data.shape[0]
        chunks = (min(n, CHUNK_SAMPLES),) + tuple(data.shape[1:]) if data.size else True
        if self.gzip_level is None or data.size == 0 or not _deflates(data):
            return group.create_dataset(name, data=data, chunks=chunks, fletcher32=True)
        chunks = (min(n, CHUNK_SAMPLES),) + (1,) * (data.ndim - 1)
        return group.create_dataset(name, data=data, chunks=chunks, shuffle=True,
                                    compression="gzip", compression_opts=self.gzip_level,
                                    fletcher32=True)

    def _create_signal(self, group, name: str, values) -> None:
        """An optional signal (``wrench``, ``sync``) as integer counts with ``scale`` /
        ``offset`` attributes when every sample is ``offset + scale * count`` bit for bit
        (A/D readings), else float32 when float32-exact, else float64."""
        grid = as_counts_memo(values) if self.store_counts else None
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
        with self._edit("writing events") as f:
            _add_events(f, events)

    def set_root_attrs(self, **attrs: Any) -> None:
        """Add or update optional root attributes (never the required ones)."""
        for key in attrs:
            if key in ROOT_ATTRS:
                raise SessionFileError(self.path, f"root attribute {key!r} is fixed at "
                                                  "creation")
        with self._edit("writing attributes") as f:
            for key, value in attrs.items():
                _set_attr(f.attrs, key, value)


_MEMO: list[tuple[Any, Any]] | None = None


@contextmanager
def counts_memo():
    """Inside the ``with`` block, :func:`as_counts_memo` computes the A/D grid of each
    array object once (the journal entry and the file encode the same trial the same way;
    the grid search is the costliest step of a trial end). The arrays must not change
    inside the block."""
    global _MEMO
    previous, _MEMO = _MEMO, []
    try:
        yield
    finally:
        _MEMO = previous


def as_counts_memo(values):
    """:func:`~nmsid.protocols.session_codec._as_counts`, remembered per array object
    inside :func:`counts_memo`."""
    if _MEMO is None:
        return _as_counts(values)
    for obj, result in _MEMO:
        if obj is values:
            return result
    result = _as_counts(values)
    _MEMO.append((values, result))
    return result


def check_seed(path, seed) -> None:
    """Refuse a seed the file cannot store (an HDF5 int64): before anything is written.

    Raises
    ------
    SessionFileError
        Naming the file, the seed and the valid range.
    """
    if seed is None:
        return
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or \
            not 0 <= int(seed) <= np.iinfo(np.int64).max:
        raise SessionFileError(path, f"seed {seed!r} is not valid: an integer in "
                                     f"[0, 2**63 - 1]")


def _add_events(f, events) -> None:
    if not events:
        return
    str_dt = _h5py().string_dtype("utf-8")
    g = f.require_group("events")
    n = len(g)
    for i, ev in enumerate(events):
        e = g.create_group(f"e{n + i + 1:05d}")
        e.attrs.create("utc", ev.utc, dtype=str_dt)
        e.attrs.create("kind", ev.kind, dtype=str_dt)
        e.attrs.create("detail", ev.detail, dtype=str_dt)


def _check_trial(trial: Trial, path) -> None:
    """Refuse a trial the reader would refuse: the same checks
    (:mod:`nmsid.protocols.session_checks`) on the attributes and samples as they would
    be stored."""
    attrs: dict[str, Any] = {k: getattr(trial, k) for k in TRIAL_FLOAT_ATTRS}
    attrs["repeat"] = trial.repeat
    attrs.update({k: getattr(trial, k) or "" for k in TRIAL_STR_ATTRS})
    found = trial_attr_findings(attrs, "trial")
    if found.problems:
        raise SessionFileError(path, "refusing to write " + "; ".join(found.problems))
    try:
        n = len(trial.force_N)
    except TypeError:
        raise SessionFileError(path, "refusing to write trial: force_N is not an array") \
            from None
    for key in TRIAL_DATASETS:
        arr = np.asarray(getattr(trial, key))
        if arr.ndim != 1 or len(arr) != n:
            raise SessionFileError(path, f"trial dataset {key} must be 1-D with {n} samples "
                             f"(as force_N), got shape {arr.shape}")
    if trial.wrench is not None and np.asarray(trial.wrench).shape != (n, 6):
        raise SessionFileError(path, f"trial dataset wrench must have shape ({n}, 6), "
                         f"got {np.asarray(trial.wrench).shape}")
    for key in (*TRIAL_DATASETS, *OPTIONAL_SIGNALS):
        values = getattr(trial, key)
        if values is None:
            continue
        try:
            block = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise SessionFileError(path, f"refusing to write trial dataset {key}: not "
                                         "numbers") from None
        problem = value_problem(key, block)
        if problem:
            raise SessionFileError(path, f"refusing to write trial dataset {key}: it "
                                         f"{problem}")


