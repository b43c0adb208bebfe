"""Lab Streaming Layer outlets for a running session: force, commanded currents, markers.

Off by default (``nmsid run --lsl``). :class:`LslObserver` wraps the session's observer and,
after passing every call on to it, publishes through pylsl (its wheels ship liblsl):

* ``<name> Force``, type ``Force``: the endpoint force, 1 channel (``force``, N) at the
  acquisition rate;
* ``<name> Stimulation``, type ``Stimulation``: the commanded currents and the reference
  ratio, 3 channels (``I_ext`` mA, ``I_flex`` mA, ``rE``), at the acquisition rate;
* ``<name> Markers``, type ``Markers`` (irregular, string): one JSON object per event,
  ``{"event": "trial_start", "trial": 3, "sE": 0.7}``, ``trial_end`` (status, rE mean),
  ``estop``, ``interlock_trip``, ``note`` and every other event of the session log by its
  kind, with its detail.

Names, types, channel labels and units follow LSL's conventions (the XDF meta-data
``desc/channels/channel`` with ``label``, ``unit``, ``type``), so LabRecorder records them
beside EMG, motion capture or PsychoPy's markers.

Time stamps: a trial's samples are stamped on LSL's clock (``pylsl.local_clock``) from its
onset, ``onset + k / fs`` for sample ``k``: one estimate per trial, no jitter between chunks.
Each chunk's arrival minus the samples it holds (``now - (start_index + n) / fs``) bounds
the onset from above (a chunk delivered late gives a later estimate, never an earlier one);
the onset is the earliest of these over the trial's first :data:`ONSET_WINDOW_S`, whose
chunks are held until then. The ``trial_start`` marker carries the same
onset, so a recording lines the marker up with the samples it marks; its error against the
stimulator's real start is what ``bench/bench_lsl.py`` measures.

Safety: a failing outlet never stops a stimulation or loses a trial. Every push is guarded;
the first failure is logged once and the LSL output is switched off for the rest of the
session; the wrapped observer (and so the session) goes on as without ``--lsl``.

Tests and benchmarks keep LSL on this machine: ``LSLAPICFG`` names a configuration with
``[multicast] ResolveScope = machine`` and ``[ports] IPv6 = disable`` (:func:`machine_only_config`).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.errors import UserError
from nmsid.rig.observer import EngineObserver

log = logging.getLogger(__name__)

MACHINE_ONLY_CFG = "[multicast]\nResolveScope = machine\n[ports]\nIPv6 = disable\n"
"""An ``lsl_api.cfg`` that keeps discovery and data on this machine (127.0.0.1)."""


ONSET_WINDOW_S = 0.2
"""A trial's first chunks are held this long; its onset is the earliest estimate among them."""


def machine_only_config(directory: Path) -> Path:
    """Write :data:`MACHINE_ONLY_CFG` into ``directory`` and point ``LSLAPICFG`` at it.

    Call before pylsl is first used (liblsl reads its configuration once)."""
    path = Path(directory) / "lsl_api.cfg"
    path.write_text(MACHINE_ONLY_CFG, encoding="utf-8")
    os.environ["LSLAPICFG"] = str(path)
    return path


def require_pylsl():
    """pylsl, or one line saying how to install it (before any device is opened)."""
    try:
        import pylsl
    except ImportError:
        raise UserError("--lsl needs pylsl: pip install nmsid[lsl] (or pip install "
                        "pylsl)") from None
    return pylsl


def lsl_observer(inner: EngineObserver, fs_Hz: float, participant: str) -> EngineObserver:
    """``inner`` with LSL outlets, or ``inner`` alone (one warning) if they cannot be made:
    LSL never keeps a session from running."""
    try:
        return LslObserver(inner, fs_Hz, participant=participant)
    except UserError:
        raise
    except Exception as exc:
        log.warning("LSL outlets could not be created (%s: %s); the session runs without "
                    "LSL", type(exc).__name__, exc)
        return inner


class LslObserver(EngineObserver):
    """The session's observer, plus LSL outlets (module docstring).

    Parameters
    ----------
    inner : EngineObserver
        The observer the session had (the CLI's progress); called first, always.
    fs_Hz : float
        The acquisition rate (the outlets' nominal rate).
    name : str
        Stream name prefix (``nmsid``); ``source_id`` is ``<name>-<participant>-<kind>``.
    participant : str
        Recorded in each stream's description and source id.
    """

    def __init__(self, inner: EngineObserver | None, fs_Hz: float, *, name: str = "nmsid",
                 participant: str = ""):
        self.inner = inner or EngineObserver()
        self.fs_Hz = float(fs_Hz)
        self.failed = ""
        self._pl = require_pylsl()
        self._onset: dict[int, float] = {}
        self._sE: dict[int, float] = {}
        self._start_detail = ""
        self._held: dict[int, list] = {}
        pl, sid = self._pl, f"{name}-{participant or 'session'}"
        self.force = pl.StreamOutlet(self._info(
            f"{name} Force", "Force", [("force", "N", "Force")], self.fs_Hz,
            pl.cf_float32, f"{sid}-force", participant), chunk_size=0, max_buffered=60)
        self.stim = pl.StreamOutlet(self._info(
            f"{name} Stimulation", "Stimulation",
            [("I_ext", "mA", "Current"), ("I_flex", "mA", "Current"), ("rE", "ratio", "Ratio")],
            self.fs_Hz, pl.cf_float32, f"{sid}-stimulation", participant), max_buffered=60)
        self.markers = pl.StreamOutlet(self._info(
            f"{name} Markers", "Markers", [("event", "", "Marker")], pl.IRREGULAR_RATE,
            pl.cf_string, f"{sid}-markers", participant), max_buffered=60)

    def _info(self, name, type_, channels, rate, fmt, source_id, participant):
        info = self._pl.StreamInfo(name, type_, len(channels), rate, fmt, source_id)
        desc = info.desc()
        desc.append_child_value("manufacturer", "nmsid")
        desc.append_child_value("participant", participant)
        chans = desc.append_child("channels")
        for label, unit, kind in channels:
            ch = chans.append_child("channel")
            ch.append_child_value("label", label)
            ch.append_child_value("unit", unit)
            ch.append_child_value("type", kind)
        return info

    # -- guarded publishing ----------------------------------------------------------------------
    def _guard(self, what: str, push) -> None:
        if self.failed:
            return
        try:
            push()
        except Exception as exc:   # an outlet must never reach the session: off, one line
            self.failed = f"{what}: {type(exc).__name__}: {exc}"
            log.warning("LSL output switched off for the rest of the session (%s); the "
                        "session goes on and records everything as without --lsl",
                        self.failed)

    def marker(self, event: str, timestamp: float | None = None, **fields: Any) -> None:
        text = json.dumps({"event": event, **fields}, default=float)
        ts = self._pl.local_clock() if timestamp is None else timestamp
        self._guard("markers", lambda: self.markers.push_sample([text], ts))

    # -- EngineObserver -------------------------------------------------------------------------
    def on_state(self, old, new, reason):
        self.inner.on_state(old, new, reason)

    def on_event(self, event):
        self.inner.on_event(event)
        if event.kind == "trial_start":   # published with the trial's onset (on_chunk)
            self._start_detail = event.detail
            return
        self.marker(event.kind, detail=event.detail, utc=event.utc)

    def on_calibration_step(self, muscle, current_mA, force_N):
        self.inner.on_calibration_step(muscle, current_mA, force_N)
        self.marker("calibration_step", muscle=muscle, current_mA=current_mA,
                    force_N=force_N)

    def on_calibration_result(self, calibration):
        self.inner.on_calibration_result(calibration)

    def on_trial_started(self, index, planned):
        self.inner.on_trial_started(index, planned)
        self._sE[index] = float(planned.sE)
        self._onset.pop(index, None)

    def on_chunk(self, index, start_index, force_N, rE, I_ext_mA, I_flex_mA):
        self.inner.on_chunk(index, start_index, force_N, rE, I_ext_mA, I_flex_mA)
        n = len(force_N)
        if n == 0 or self.failed:
            return
        if index in self._onset:
            self._push(index, start_index, force_N, rE, I_ext_mA, I_flex_mA)
            return
        # the onset: arrival minus the samples held, the earliest of the first chunks
        # (a chunk delivered late only makes its estimate later)
        estimate = self._pl.local_clock() - (start_index + n) / self.fs_Hz
        held = self._held.setdefault(index, [])
        held.append((estimate, (start_index, force_N, rE, I_ext_mA, I_flex_mA)))
        if start_index + n >= ONSET_WINDOW_S * self.fs_Hz:
            self._release(index)

    def _release(self, index) -> None:
        """Fix the trial's onset from its held chunks, mark it, push them."""
        held = self._held.pop(index, [])
        if not held:
            return
        self._onset[index] = t0 = min(e for e, _ in held)
        self.marker("trial_start", t0, trial=int(index), sE=self._sE.get(index),
                    detail=self._start_detail)
        self._start_detail = ""
        for _, chunk in held:
            self._push(index, *chunk)

    def _push(self, index, start_index, force_N, rE, I_ext_mA, I_flex_mA) -> None:
        n = len(force_N)
        ts = (self._onset[index] + (start_index + np.arange(n)) / self.fs_Hz).tolist()
        f = np.asarray(force_N, np.float32).reshape(-1, 1)
        s = np.column_stack([np.asarray(I_ext_mA, np.float32),
                             np.asarray(I_flex_mA, np.float32), np.asarray(rE, np.float32)])
        self._guard("force", lambda: self.force.push_chunk(f.tolist(), ts))
        self._guard("stimulation", lambda: self.stim.push_chunk(s.tolist(), ts))

    def on_target(self, index, start_index, target_N):
        self.inner.on_target(index, start_index, target_N)

    def on_trial_finished(self, index, trial):
        self.inner.on_trial_finished(index, trial)
        self._release(index)                 # a trial shorter than the onset window
        t0 = self._onset.get(index)
        ts = None if t0 is None else t0 + trial.n_samples / self.fs_Hz
        rE = np.asarray(trial.rE, float)
        self.marker("trial_end", ts, trial=int(index), name=trial.name, sE=float(trial.sE),
                    rE_mean=float(rE.mean()) if rE.size else None, status=trial.status,
                    reason=trial.abort_reason or "")

    def on_level_completed(self, sE, trials):
        self.inner.on_level_completed(sE, trials)

    def on_finished(self, path):
        self.inner.on_finished(path)
        self.marker("session_finished", path=str(path))


# -- recording other streams into the session file --------------------------------------------
class LslRecorder:
    """Records the LSL streams the operator names (``nmsid run --lsl-record EMG``) for the
    length of the session and appends them to the session file as optional items.

    Each stream whose name or type matches one of ``wanted`` is read by its own inlet from
    :meth:`start` to :meth:`stop` (a background thread; nothing here can stop the session).
    :meth:`write` appends ``/lsl/<run>/<stream name>`` with ``time_series``, ``time_stamps``
    (the stream's own LSL clock) and attributes ``name``, ``type``, ``source_id``,
    ``nominal_srate``, ``clock_offset_s`` (mean of ``clock_offsets_s``, liblsl's
    ``time_correction``: add it to ``time_stamps`` for this machine's LSL clock, on which
    nmsid's own outlets and trial onsets are stamped), and the group's
    ``trial_onsets_lsl_json`` (trial index -> onset on this machine's LSL clock).
    """

    def __init__(self, wanted: list[str], *, wait_s: float = 2.0):
        import threading
        self._pl = require_pylsl()
        self.wanted = [w for w in wanted if w]
        self.inlets: list[Any] = []
        self.data: list[dict] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="lsl-recorder", daemon=True)
        found = self._pl.resolve_streams(wait_s)
        for info in found:
            if info.name() in self.wanted or info.type() in self.wanted:
                if info.source_id().startswith("nmsid"):
                    continue                 # nmsid's own outlets: the session has them
                inlet = self._pl.StreamInlet(info, max_buflen=360)
                self.inlets.append(inlet)
                self.data.append({"info": info, "x": [], "t": [], "offsets": []})
        missing = [w for w in self.wanted
                   if not any(w in (d["info"].name(), d["info"].type()) for d in self.data)]
        if missing:
            log.warning("LSL: no stream named or typed %s on the network; not recorded",
                        ", ".join(missing))

    def start(self) -> LslRecorder:
        for inlet, d in zip(self.inlets, self.data, strict=True):
            try:
                inlet.open_stream(2.0)
                d["offsets"].append(inlet.time_correction(2.0))
            except Exception as exc:
                log.warning("LSL: stream %s not opened (%s)", d["info"].name(), exc)
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._stop.is_set():
            for inlet, d in zip(self.inlets, self.data, strict=True):
                try:
                    x, t = inlet.pull_chunk(timeout=0.0)
                except Exception as exc:
                    log.warning("LSL: stream %s lost (%s)", d["info"].name(), exc)
                    continue
                d["x"] += x
                d["t"] += t
            self._stop.wait(0.02)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for inlet, d in zip(self.inlets, self.data, strict=True):
            try:
                x, t = inlet.pull_chunk(timeout=0.2)
                d["x"] += x
                d["t"] += t
                d["offsets"].append(inlet.time_correction(1.0))
            except Exception as exc:
                log.warning("LSL: stream %s at the end: %s", d["info"].name(), exc)

    def write(self, path: Path, onsets: dict[int, float]) -> str:
        """Append the recorded streams to ``path`` (a sidecar ``<path>.lsl.h5`` if the
        session file is not there); returns the group written."""
        import datetime

        import h5py
        target = Path(path) if Path(path).exists() else Path(str(path) + ".lsl.h5")
        run = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
        with h5py.File(target, "a") as f:
            g = f.require_group("lsl").create_group(run)
            g.attrs["trial_onsets_lsl_json"] = json.dumps({str(k): v for k, v in
                                                           onsets.items()})
            for d in self.data:
                info = d["info"]
                name = "".join(c if c.isalnum() or c in "-_ " else "_" for c in info.name())
                s = g.create_group(name or "stream")
                if info.channel_format() == self._pl.cf_string:
                    s.create_dataset("time_series", data=np.asarray(d["x"], dtype=object),
                                     dtype=h5py.string_dtype())
                else:
                    s.create_dataset("time_series", data=np.asarray(d["x"], float))
                s.create_dataset("time_stamps", data=np.asarray(d["t"], float))
                offs = np.asarray(d["offsets"], float)
                s.create_dataset("clock_offsets_s", data=offs)
                s.attrs.update({"name": info.name(), "type": info.type(),
                                "source_id": info.source_id(),
                                "nominal_srate": info.nominal_srate(),
                                "clock_offset_s": float(offs.mean()) if offs.size else 0.0})
        return f"{target}:/lsl/{run}"


def start_recording(wanted: list[str] | None) -> LslRecorder | None:
    """An :class:`LslRecorder` started for ``wanted``, or None (nothing asked, or one
    warning if it could not start: LSL never keeps a session from running)."""
    if not wanted:
        return None
    try:
        return LslRecorder(list(wanted)).start()
    except UserError:
        raise
    except Exception as exc:
        log.warning("LSL recording not started (%s: %s); the session runs without it",
                    type(exc).__name__, exc)
        return None


def finish_recording(recorder: LslRecorder | None, path: Path, observer: Any) -> None:
    """Stop ``recorder`` and append what it recorded to the session file (never raises)."""
    if recorder is None:
        return
    try:
        recorder.stop()
        onsets = dict(observer._onset) if isinstance(observer, LslObserver) else {}
        where = recorder.write(path, onsets)
        log.info("LSL streams recorded into %s", where)
    except Exception as exc:
        log.warning("LSL streams could not be written (%s: %s); the session file is "
                    "unchanged", type(exc).__name__, exc)
