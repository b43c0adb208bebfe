"""Host-streamed stimulation on the simulated stimulator (closed loop).

:class:`StreamingStimulator` gives :class:`nmsid.sim_backends.stimulator.SimStimulator` the
capability :class:`nmsid.drivers.interfaces.HostStreamedStimulator`:

* :meth:`~StreamingStimulator.open_stream` fixes the ceilings (never above the device's
  range) and the update rate for the whole stream. The rate used makes every update last
  a whole number of carrier periods and of acquisition samples, and updates start at the
  trigger (carrier phase 0): the amplitude is constant over each carrier period, so each
  period of the charge-balanced carrier carries zero net charge.
* :meth:`~StreamingStimulator.write_stream` checks every amplitude against the stream's
  ceilings *before* anything is queued (:class:`~nmsid.drivers.interfaces.CurrentLimitError`,
  nothing queued), then quantises downwards (never above what was asked). An update is
  queued after the last one and never changes output already delivered; a host that
  writes late leaves the output at zero for the missed updates (an underrun, counted).
* ``stop_now`` (the core stimulator's) ends a stream with output at zero at once;
  :meth:`~StreamingStimulator.close_stream` after the queued updates.

The stream is one run of the simulated world (``SimWorld.start_run``) whose envelope is
filled while it plays; during it the rig hands over force and simulates ahead one update
at a time, so an update written after a chunk was read acts on the next samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nmsid.drivers.interfaces import (
    CurrentLimitError,
    StimulatorCapabilities,
    StimulatorState,
)
from nmsid.sim_backends.errors import DeviceStateError, SimConfigError

if TYPE_CHECKING:   # the stimulator this mixes into (no import cycle at run time)
    from nmsid.sim_backends.world import SimWorld

STREAM_MAX_S = 600.0
"""Longest stream (its envelope is allocated at :meth:`StreamingStimulator.open_stream`)."""
STREAM_QUEUE_UPDATES = 64
"""Updates the simulated device queues ahead of its output (``stream_space``)."""
DEFAULT_CARRIER_HZ = 1000.0
"""The sine carrier of a stream unless ``open_stream(carrier_Hz=...)`` names another."""


@dataclass
class StreamState:
    """One open stream."""

    ceiling_ext_mA: float
    ceiling_flex_mA: float
    rate_Hz: float
    carrier_Hz: float
    samples_per_update: int
    """Acquisition samples each update lasts."""
    I_ext_mA: np.ndarray
    """Queued (quantised) amplitudes; zeros beyond ``written``."""
    I_flex_mA: np.ndarray
    written: int = 0
    """Updates queued from the trigger on (the next write goes here, or later)."""
    underrun_updates: int = 0
    """Updates the host wrote too late (output zero for them)."""
    saved_chunk_block: tuple[int, int] = (0, 0)
    started: bool = False


def stream_rate(update_Hz: float, carrier_Hz: float, fs_Hz: float) -> tuple[float, int]:
    """The update rate used for a requested one: whole carrier periods per update, and a
    whole number of acquisition samples.

    Returns
    -------
    (rate_Hz, samples_per_update)

    Raises
    ------
    SimConfigError
        If no such rate exists near the request.
    """
    if not (math.isfinite(update_Hz) and update_Hz > 0):
        raise SimConfigError(f"stream update rate {update_Hz!r} Hz must be a number > 0")
    k = max(1, round(carrier_Hz / update_Hz))      # carrier periods per update
    for kk in (k, *range(k + 1, k + 64)):
        spu = fs_Hz * kk / carrier_Hz
        if abs(spu - round(spu)) < 1e-9 and round(spu) >= 1:
            return carrier_Hz / kk, round(spu)
    raise SimConfigError(f"no stream rate near {update_Hz:g} Hz lasts whole carrier periods "
                         f"({carrier_Hz:g} Hz) and whole samples ({fs_Hz:g} Hz)")


class StreamingStimulator:
    """Mixin of :class:`~nmsid.sim_backends.stimulator.SimStimulator`: the stream methods."""

    _stream: StreamState | None = None
    if TYPE_CHECKING:   # provided by SimStimulator
        _w: SimWorld
        _caps: StimulatorCapabilities
        _state: StimulatorState
        _loaded: tuple[np.ndarray, np.ndarray, float, bool] | None

        def _check_usable(self, what: str) -> None: ...

        def _current_state(self) -> StimulatorState: ...

        def _quantise(self, arr: np.ndarray) -> np.ndarray: ...
    last_stream: StreamState | None = None
    """The most recent stream, kept after it closed (queued amplitudes, underruns)."""

    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float, update_Hz: float,
                    *, carrier_Hz: float = DEFAULT_CARRIER_HZ,
                    max_s: float = STREAM_MAX_S) -> float:
        """Prepare a stream (ceilings fixed for its whole length); return the rate used.

        Raises
        ------
        CurrentLimitError
            If a ceiling is not a finite number >= 0.
        SimConfigError
            If the rate or carrier cannot be rendered.
        """
        w = self._w
        caps = self._caps
        ceilings = []
        for name, c in (("ceiling_ext_mA", ceiling_ext_mA), ("ceiling_flex_mA", ceiling_flex_mA)):
            c = float(c)
            if not (math.isfinite(c) and c >= 0):
                raise CurrentLimitError(f"stream {name} must be a finite number >= 0, got {c!r}")
            ceilings.append(min(c, caps.max_current_mA))
        if not 0 < carrier_Hz <= caps.output_rate_Hz / 4:
            raise SimConfigError(f"carrier {carrier_Hz:g} Hz cannot be rendered: must be in "
                                 f"(0, {caps.output_rate_Hz / 4:g}] Hz")
        with w.lock:
            self._check_usable("open_stream")
            if self._current_state() is StimulatorState.RUNNING:
                raise DeviceStateError("open_stream() while the stimulator is running")
            self._restore_stream_chunks()
            rate, spu = stream_rate(float(update_Hz), float(carrier_Hz), w.fs_Hz)
            n = math.ceil(max_s * rate)
            st = StreamState(ceilings[0], ceilings[1], rate, float(carrier_Hz), spu,
                             np.zeros(n), np.zeros(n), saved_chunk_block=(w.chunk_n, w.block_n))
            # the force of an update is handed over as soon as it is played: no more
            w.chunk_n = w.block_n = spu
            self._stream = st
            self._loaded = (st.I_ext_mA, st.I_flex_mA, rate, True)
            self._state = StimulatorState.LOADED
            return rate

    def _restore_stream_chunks(self) -> None:
        st = self._stream
        if st is not None:
            self._w.chunk_n, self._w.block_n = st.saved_chunk_block
            self.last_stream = st
            self._stream = None

    def _first_writable(self, st: StreamState) -> int:
        """The first update not (even partly) delivered yet."""
        w = self._w
        run = w.run
        if not st.started or run is None:
            return 0
        done = max(w.committed, w.sample_at(w.now())) - run.N_trigger
        return max(0, -(-done // st.samples_per_update))

    def write_stream(self, I_ext_mA, I_flex_mA) -> None:
        """Queue the next amplitudes (mA, one per update), each checked against the stream's
        ceilings first: a single sample above one refuses the whole write, nothing queued.

        Raises
        ------
        CurrentLimitError
            A sample negative, not finite or above its ceiling (nothing queued).
        DeviceStateError
            Without an open stream, or beyond its length / queue.
        """
        st = self._stream
        if st is None:
            raise DeviceStateError("write_stream() without an open stream (open_stream())")
        arrs = []
        for name, arr, ceiling in (("I_ext_mA", I_ext_mA, st.ceiling_ext_mA),
                                   ("I_flex_mA", I_flex_mA, st.ceiling_flex_mA)):
            a = np.array(arr, dtype=float, ndmin=1)
            if a.ndim != 1:
                raise CurrentLimitError(f"stream {name} must be 1-D, got shape {a.shape}")
            if a.size and not np.all(np.isfinite(a)):
                raise CurrentLimitError(f"stream {name} holds non-finite amplitudes; nothing "
                                        "was queued")
            if a.size and a.min() < 0:
                raise CurrentLimitError(f"stream {name} holds a negative amplitude "
                                        f"({a.min():.3f} mA); nothing was queued")
            if a.size and a.max() > ceiling:
                raise CurrentLimitError(f"stream {name} amplitude {a.max():.3f} mA exceeds the "
                                        f"stream's ceiling {ceiling:.3f} mA; nothing was queued")
            arrs.append(self._quantise(a))
        q_e, q_f = arrs
        if q_e.size != q_f.size:
            raise CurrentLimitError(f"stream I_ext_mA and I_flex_mA must have the same length, "
                                    f"got {q_e.size} and {q_f.size}")
        w = self._w
        with w.lock:
            self._check_usable("write_stream")
            first = self._first_writable(st)
            if first > st.written:
                st.underrun_updates += first - st.written
                st.written = first
            lo, hi = st.written, st.written + q_e.size
            if hi > st.I_ext_mA.size:
                raise DeviceStateError(f"write_stream() beyond the stream's length "
                                       f"({st.I_ext_mA.size} updates)")
            st.I_ext_mA[lo:hi] = q_e
            st.I_flex_mA[lo:hi] = q_f
            st.written = hi
            if q_e.size:
                w.max_sent_mA[0] = max(w.max_sent_mA[0], float(q_e.max()))
                w.max_sent_mA[1] = max(w.max_sent_mA[1], float(q_f.max()))
            run = w.run
            if st.started and run is not None and w.records:
                rec = w.records[-1]
                rec.max_ext_mA = max(rec.max_ext_mA, float(q_e.max(initial=0.0)))
                rec.max_flex_mA = max(rec.max_flex_mA, float(q_f.max(initial=0.0)))
                blk = w._blk
                if blk is not None and blk.N1 > run.N_trigger + lo * st.samples_per_update:
                    w.invalidate()   # simulated ahead with the old (zero) amplitudes

    def stream_space(self) -> int:
        """Updates that can be queued now (the device's queue, the stream's length)."""
        st = self._stream
        if st is None:
            return 0
        with self._w.lock:
            ahead = st.written - self._first_writable(st)
            return int(max(0, min(STREAM_QUEUE_UPDATES - ahead, st.I_ext_mA.size - st.written)))

    def close_stream(self) -> None:
        """End the stream after the queued updates (output zero from there). Idempotent."""
        st = self._stream
        if st is None:
            return
        w = self._w
        with w.lock:
            run = w.run
            if st.started and run is not None:
                end = run.N_trigger + max(st.written, self._first_writable(st)) \
                    * st.samples_per_update
                w._stop_run(end, "stream closed", w.now())
            elif self._state in (StimulatorState.LOADED, StimulatorState.ARMED):
                self._loaded = None
                self._state = StimulatorState.IDLE
            self._restore_stream_chunks()

    # -- for tests and the session record ------------------------------------------------
    @property
    def stream(self) -> StreamState | None:
        """The open stream (None when closed)."""
        return self._stream

    def _stream_started(self) -> None:
        if self._stream is not None:
            self._stream.started = True
