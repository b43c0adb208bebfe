"""Write one session file as an NWB file (Neurodata Without Borders, the DANDI format).

Layout of the NWB file (a choice, documented in README "Sharing"):

* ``subject``: the participant code only; species *Homo sapiens*; age and sex unknown
  (``sex="U"``; age left out because nmsid never stores it).
* devices ``stimulator``, ``ad_converter`` and ``force_sensor`` (descriptions from the session's
  backend and configuration).
* one series per trial and signal, each with its own ``starting_time`` (per-trial
  series rather than one concatenated timeline: trials are separated by rest periods
  whose samples were never recorded, and a rate-based series must be gap-free).
  Stimulus: ``rE_tNNN`` (unit ``1``), ``I_ext_tNNN`` / ``I_flex_tNNN`` (unit ``A``,
  data in mA, ``conversion=1e-3``). Acquisition: ``force_tNNN`` (unit ``N``, extension
  positive), ``wrench_force_tNNN`` (Fx, Fy, Fz in N) and ``wrench_moment_tNNN``
  (Mx, My, Mz in N*m) in the raw sensor frame, ``sync_tNNN`` if recorded.
* the trials table: ``start_time``, ``stop_time`` plus ``trial_name``, ``sE``,
  ``repeat``, ``status``, ``abort_reason``, ``started_utc``.
* events as the NWB ``EventsTable`` ``events`` (timestamp, kind, detail).
* processing module ``misc`` with the tables ``calibration`` (quantity, value: the six
  calibration values), ``session_metadata`` (key, value: seed, backend, software, source
  file and the configuration flattened to dotted keys with JSON values) and one
  ``calibration_<ramp>`` table per calibration ramp.

Trial start times: seconds from ``created_utc`` to the trial's ``started_utc``, raised
when needed so that a trial never starts before the previous one ended; trials without
``started_utc`` follow the previous one directly. The rig writes ``started_utc`` and event
times as monotonic offsets (millisecond resolution) from the UTC time read when the
writer opened the session (:mod:`nmsid.rig.session_clock`), so a step of the computer's
clock (recorded as a ``clock_step`` event) shifts no trial; files written before that
have one-second wall-clock times, which the "raised when needed" rule keeps in order.

pynwb is an optional dependency (extra ``nwb``), imported inside the functions.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nmsid.errors import OutputExistsError
from nmsid.export.errors import ExportError
from nmsid.protocols.session_file import Session, read_session

CALIBRATION_FIELDS = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")


def _parse_utc(text: str) -> _dt.datetime | None:
    if not text:
        return None
    try:
        t = _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.UTC)
    return t


def _flatten(value, prefix: str = "") -> dict[str, str]:
    """A nested configuration as ``{"a.b": json_value}`` (no dictionaries left)."""
    if isinstance(value, dict):
        out: dict[str, str] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: json.dumps(value)}


def trial_start_times_s(session: Session) -> np.ndarray:
    """Start of each trial in s after the session start (see the module docstring)."""
    t0 = _parse_utc(session.created_utc)
    out = np.zeros(len(session.trials))
    earliest = 0.0
    for i, trial in enumerate(session.trials):
        t = _parse_utc(trial.started_utc)
        start = (t - t0).total_seconds() if t is not None and t0 is not None else earliest
        start = max(start, earliest)
        out[i] = start
        earliest = start + trial.n_samples / trial.fs_Hz
    return out


@dataclass
class NwbExport:
    """What :func:`export_nwb` wrote."""

    path: Path
    n_trials: int
    n_series: int
    n_events: int


def _compressed(data: np.ndarray):
    from hdmf.backends.hdf5.h5_utils import H5DataIO  # optional dependency (extra nwb)
    if data.size == 0:
        return data
    return H5DataIO(data, compression="gzip", compression_opts=4, shuffle=True)


DEFAULT_SUBJECT_AGE = "P18Y/"
"""ISO 8601 age range given to NWB: adult, exact age unknown. nmsid never records age;
NWB (and nwbinspector) need age or date of birth, and a range with an open end is the
NWB way to say "at least 18 years". Override with ``--subject-age`` (e.g. ``P34Y``)."""


def build_nwbfile(session: Session, *, subject_age: str = DEFAULT_SUBJECT_AGE,
                  experimenter: list[str] | None = None, institution: str | None = None):
    """The ``pynwb.NWBFile`` for a session read with :func:`read_session`, and the number
    of time series in it."""
    # pynwb is optional (extra "nwb") and slow to import: load it only when exporting
    from hdmf.common import DynamicTable, VectorData
    from pynwb import NWBFile, ProcessingModule, TimeSeries
    from pynwb.file import Subject

    start = _parse_utc(session.created_utc)
    if start is None:
        raise ExportError(f"{session.path}: created_utc {session.created_utc!r} is not an "
                          "ISO 8601 UTC time; NWB needs the session start time")
    backend = session.backend or "unknown"
    identifier = str(uuid.uuid5(uuid.NAMESPACE_URL,
                                f"nmsid:{session.participant}:{session.created_utc}"))
    nwb = NWBFile(
        session_description=(
            "FES identification of the elbow neuromuscular system: per trial a constant "
            "EAA sum sE, rE = 0.5 lead-in then an exponential rE chirp; endpoint force "
            f"recorded (nmsid session, backend {backend})"),
        identifier=identifier,
        session_start_time=start,
        experiment_description="Identification of Kp, wn, zeta per sE level (nmsid)",
        session_id=Path(session.path).stem,
        source_script=session.software,
        source_script_file_name=Path(session.path).name,
        keywords=["functional electrical stimulation", "system identification",
                  "elbow", "neuromuscular", "force"],
        experimenter=experimenter or None,
        institution=institution,
    )
    nwb.subject = Subject(subject_id=session.participant, species="Homo sapiens", sex="U",
                          age=subject_age,
                          description="participant code only; nmsid records neither age "
                                      f"nor sex (age given as {subject_age!r})")
    config = session.config
    nwb.create_device(name="stimulator", description=(
        f"two-channel current-controlled stimulator ({backend}); extensor and flexor "
        "channels, carrier amplitude commanded per sample"))
    nwb.create_device(name="ad_converter",
                      description=f"analog-to-digital acquisition ({backend})")
    nwb.create_device(name="force_sensor", description=(
        f"force/torque sensor at the wrist ({backend}); force_N is the force along the "
        "extension axis, wrench is Fx..Mz in the raw sensor frame"))

    starts = trial_start_times_s(session)
    n_series = 0
    for trial, t0 in zip(session.trials, starts, strict=True):
        tag = trial.name
        common = {"starting_time": float(t0), "rate": float(trial.fs_Hz)}
        nwb.add_stimulus(TimeSeries(
            name=f"rE_{tag}", data=_compressed(trial.rE), unit="1",
            description="commanded EAA ratio rE (dimensionless, 0..1)", **common))
        for key, label in (("I_ext_mA", "I_ext"), ("I_flex_mA", "I_flex")):
            nwb.add_stimulus(TimeSeries(
                name=f"{label}_{tag}", data=_compressed(getattr(trial, key)), unit="A",
                conversion=1e-3, description=f"commanded carrier amplitude of the "
                f"{'extensor' if label == 'I_ext' else 'flexor'} channel (stored in mA)",
                **common))
        nwb.add_acquisition(TimeSeries(
            name=f"force_{tag}", data=_compressed(trial.force_N), unit="N",
            description="measured endpoint force along the extension axis, extension "
                        "positive", **common))
        n_series += 4
        if trial.wrench is not None:
            w = np.asarray(trial.wrench)
            nwb.add_acquisition(TimeSeries(
                name=f"wrench_force_{tag}", data=_compressed(w[:, :3]), unit="N",
                description="Fx, Fy, Fz in the raw sensor frame", **common))
            nwb.add_acquisition(TimeSeries(
                name=f"wrench_moment_{tag}", data=_compressed(w[:, 3:]), unit="N*m",
                description="Mx, My, Mz in the raw sensor frame", **common))
            n_series += 2
        if trial.sync is not None:
            nwb.add_acquisition(TimeSeries(
                name=f"sync_{tag}", data=_compressed(np.asarray(trial.sync)), unit="V",
                description="the stimulator's sync output as recorded by the A/D",
                **common))
            n_series += 1

    for col, desc in (("trial_name", "trial group in the session file (t001, ...)"),
                      ("sE", "EAA sum held during the trial"),
                      ("repeat", "repetition of this sE (1, 2, 3, ...)"),
                      ("status", "completed or aborted"),
                      ("abort_reason", "why the trial was aborted (empty when completed)"),
                      ("started_utc", "when stimulation began (ISO 8601 UTC)")):
        nwb.add_trial_column(name=col, description=desc)
    for trial, t0 in zip(session.trials, starts, strict=True):
        nwb.add_trial(start_time=float(t0), stop_time=float(t0 + trial.n_samples / trial.fs_Hz),
                      trial_name=trial.name, sE=float(trial.sE), repeat=int(trial.repeat),
                      status=trial.status, abort_reason=trial.abort_reason,
                      started_utc=trial.started_utc)

    if session.events:
        table = nwb.create_events_table(
            name="events", description="the session's event log (E-stops, interlock trips, "
            "pauses, resumes, clock steps, notes); timestamp = the event's UTC time (the "
            "session's monotonic clock) minus the session start",
            source_description="nmsid rig engine")
        table.add_column(name="kind", description="what happened (estop, pause, ...)")
        table.add_column(name="detail", description="free-text detail")
        rows = []
        for ev in session.events:
            t = _parse_utc(ev.utc)
            rows.append((max(0.0, (t - start).total_seconds()) if t is not None else 0.0,
                         ev.kind, ev.detail or ""))
        for t_s, kind, detail in sorted(rows, key=lambda r: r[0]):
            table.add_row(timestamp=t_s, kind=kind, detail=detail)

    module = ProcessingModule(name="misc", description="nmsid session calibration and "
                              "configuration")
    nwb.add_processing_module(module)
    cal = session.calibration
    module.add(DynamicTable(
        name="calibration", description="currents at which each muscle alone produced "
        "Fmin_N / Fmax_N (one row per quantity)",
        columns=[VectorData(name="quantity", description="name in the session file",
                            data=list(CALIBRATION_FIELDS)),
                 VectorData(name="value", description="value in the unit of the name's "
                            "suffix (_mA or _N)",
                            data=[float(getattr(cal, k)) for k in CALIBRATION_FIELDS])]))
    meta = {"seed": "" if session.seed is None else str(int(session.seed)),
            "backend": backend, "software": session.software,
            "source_file": Path(session.path).name}
    meta.update({f"config.{k}": v for k, v in _flatten(config).items()})
    module.add(DynamicTable(
        name="session_metadata", description="seed, backend, software, source file and the "
        "protocol configuration flattened to dotted keys (values as JSON)",
        columns=[VectorData(name="key", description="setting", data=list(meta)),
                 VectorData(name="value", description="value (config values as JSON)",
                            data=[str(v) for v in meta.values()])]))
    for ramp, data in sorted(cal.ramps.items()):
        arr = np.asarray(data, dtype=float)
        if arr.ndim != 1 or arr.size < 2:
            continue
        module.add(DynamicTable(
            name=f"calibration_{ramp}", description=f"calibration ramp dataset {ramp}",
            columns=[VectorData(name=ramp, description=ramp, data=arr)]))
    return nwb, n_series


def export_nwb(session_path: str | os.PathLike, out_path: str | os.PathLike, *,
               subject_age: str = DEFAULT_SUBJECT_AGE, experimenter: list[str] | None = None,
               institution: str | None = None) -> NwbExport:
    """Export one session file to NWB.

    Parameters
    ----------
    session_path : path-like
        The nmsid session file (``.h5``; compressed or not).
    out_path : path-like
        The ``.nwb`` file to create; an existing file is never overwritten.
    subject_age : str
        ISO 8601 duration or range (default ``P18Y/``: adult, exact age unknown).
    experimenter, institution : optional
        NWB metadata nmsid does not know (nwbinspector suggests them).

    Returns
    -------
    NwbExport

    Raises
    ------
    FileExistsError
        If ``out_path`` exists.
    protocols.session_file.SessionFileError, ExportError
        If the session cannot be read or exported.
    """
    out = Path(out_path)
    if out.exists():
        raise OutputExistsError(f"{out}: a file already exists here; choose another --out "
                              "(nmsid never overwrites)")
    session = read_session(session_path)
    nwb, n_series = build_nwbfile(session, subject_age=subject_age,
                                  experimenter=experimenter, institution=institution)
    from pynwb import NWBHDF5IO  # optional dependency (extra nwb)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".partial.nwb")
    try:
        with NWBHDF5IO(str(tmp), "w") as io:
            io.write(nwb)
        if out.exists():
            raise OutputExistsError(f"{out}: appeared while exporting; not overwritten")
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return NwbExport(out, len(session.trials), n_series, len(session.events))


def inspect_nwb(path: str | os.PathLike) -> list:
    """nwbinspector's findings for an NWB file (list of ``InspectorMessage``)."""
    # nwbinspector is optional (extra nwb) and slow to import
    from nwbinspector import inspect_nwbfile
    return list(inspect_nwbfile(nwbfile_path=str(path)))
