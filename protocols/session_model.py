"""The session file's data model: the contract's names, and the objects a file holds.

See ``shared/spec/session-file-v1.md``. :mod:`nmsid.protocols.session_writer` writes these
objects, :mod:`nmsid.protocols.session_reader` reads them and
:mod:`nmsid.protocols.session_validator` checks a file against the contract;
:mod:`nmsid.protocols.session_file` re-exports all of it.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmsid.protocols.errors import SessionExistsError, SessionFileError  # noqa: F401 (re-export)
from nmsid.protocols.reprs import counted, html_repr, number_span, short_repr

FORMAT = "nmsid-session"
FORMAT_VERSION = 1
PARTICIPANT_PATTERN = re.compile(r"\A[A-Za-z0-9_-]{1,64}\Z")
"""A participant code (``\\Z``, not ``$``: ``"P01\\n"`` is refused)."""
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
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


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
        """Every way these values break the contract (empty when valid): the same checks
        the reader applies to a stored calibration
        (:func:`nmsid.protocols.session_checks.calibration_findings`)."""
        # function-local: session_checks imports this module (the contract's names)
        from nmsid.protocols.session_checks import calibration_findings
        return calibration_findings({k: getattr(self, k) for k in CALIBRATION_ATTRS}).problems

    def __repr__(self) -> str:
        return short_repr("Calibration",
                          f"extensor {self.Iemin_mA:g}-{self.Iemax_mA:g} mA",
                          f"flexor {self.Ifmin_mA:g}-{self.Ifmax_mA:g} mA",
                          f"force {self.Fmin_N:g}-{self.Fmax_N:g} N",
                          f"ramps {', '.join(self.ramps)}" if self.ramps else "")

    _repr_html_ = html_repr


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

    def __repr__(self) -> str:
        status = self.status if self.completed else f"{self.status} ({self.abort_reason})"
        duration = self.n_samples / self.fs_Hz if self.fs_Hz > 0 else float("nan")
        return short_repr(f"Trial {self.name}".rstrip(), f"sE {self.sE:g}",
                          f"repeat {self.repeat}", status,
                          f"{self.n_samples} samples at {self.fs_Hz:g} Hz ({duration:.3g} s)",
                          "wrench" if self.wrench is not None else "",
                          "sync" if self.sync is not None else "")

    _repr_html_ = html_repr


@dataclass
class Event:
    """One entry of the session's event log."""

    utc: str
    kind: str
    detail: str = ""

    def __repr__(self) -> str:
        detail = self.detail if len(self.detail) <= 200 else self.detail[:197] + "..."
        return short_repr("Event", self.utc, self.kind, repr(detail) if detail else "")


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
    warnings: list[str] = field(default_factory=list)
    """Implausible values the contract allows (a current above the recording stimulator's
    range, a force beyond an elbow's): the file is read; analyses repeat these."""

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

    def __repr__(self) -> str:
        n_done = len(self.completed_trials())
        levels = self.sE_levels()
        rates = number_span(t.fs_Hz for t in self.trials)
        return short_repr(
            "Session", self.participant or "no participant",
            counted(len(self.trials), "trial")
            + ("" if n_done == len(self.trials) else f" ({n_done} completed)"),
            f"{counted(len(levels), 'sE level')} {number_span(levels)}" if levels else "",
            f"{rates} Hz" if rates else "", self.backend, self.created_utc,
            counted(len(self.warnings), "warning") if self.warnings else "",
            str(self.path))

    _repr_html_ = html_repr


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




_DAMAGE_ERRORS = (KeyError, OSError, RuntimeError, ValueError, SystemError, IndexError,
                  TypeError, OverflowError)
"""What h5py raises when a damaged file (cut short by a crash, a flipped bit) is read:
found by the session-file fuzz (``bench/bench_fuzz_sessions.py``); SystemError comes
from an exception inside an HDF5 link-visit callback."""


def _trial_names(group) -> list[str]:
    numbered = [(int(m.group(1)), k) for k in group if (m := TRIAL_NAME_PATTERN.match(k))]
    return [k for _, k in sorted(numbered)]
