"""Volts from the force sensor's analog outputs -> wrench and endpoint force (N).

The Leptrino sensor's analog outputs (one voltage per axis, through its amplifier) are
digitised by the A/D (Contec or NI). The calibration comes from the sensor's data sheet /
calibration certificate and is written in the hardware configuration:

* per axis, ``rated`` (N or N m at full load) and ``rated_output_V`` (volts at that load),
  so ``value = (V - offset_V) * rated / rated_output_V``; or
* a 6 x 6 ``matrix`` (N and N m per V) applied to the six offset-corrected voltages
  (cross-talk compensation), which needs all six axes wired.

The endpoint force along the extension axis (extension positive) is
``extension_direction . (Fx, Fy, Fz)`` with a unit direction in the sensor frame.
A sample within ``saturation_fraction`` of the A/D range is flagged as over-range, and so
is one at the edge of the SENSOR's own output span: the Leptrino analog outputs span
0 .. 3.3 V, 1.5 V at no load, 1 V per rated load (CFS manual No.M000104, 4.1: "each signal
line outputs 0 to 3.3 V; the offset voltage is 1.5 V ... rated voltage 1 V"), so a force
beyond about -1.5 / +1.8 x rated clips there, far inside a +-10 V A/D range
(:data:`SENSOR_SPAN_V`, ``sensor_span_V``).

Automatic tare (:class:`NoLoadTare`): the configured ``offset_V`` is a nominal figure (the
manual's 1.5 V), but a real sensor rests off it (the manual's own examples rest at 1.532
and 1.580 V: 40 N on a 500 N axis), and the manual computes force from the change relative
to the MEASURED no-load voltage (CFS manual 4.2). So the A/D drivers measure the no-load
voltages before the first block of a session and before each block that follows a rest
(:data:`REST_BEFORE_TARE_S` of idle A/D), and every force they return, the one the
interlock's force limit acts on, is relative to them.

``monitor_channel`` (the dry run's only): the A/D input wired across the dummy-load
resistor (``nmsid probe --dry-run``); its volts are passed on unconverted, like the sync's.
A session's calibration has none.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from nmsid.drivers.errors import DeviceError

log = logging.getLogger(__name__)

AXES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
SENSOR_SPAN_V = (0.0, 3.3)
"""CFS manual No.M000104, 4.1: each analog output spans 0 .. 3.3 V."""
SENSOR_OFFSET_V = 1.5
"""CFS manual 4.1: "the offset voltage is 1.5 V" (no load)."""
SENSOR_RATED_OUTPUT_V = 1.0
"""CFS manual 4.1: the change from the offset at rated load is 1 V ("rated voltage 1 V")."""
SPAN_EDGE_V = 0.02
"""A sample within this of either end of the sensor's span is taken as clipped."""
TARE_WINDOW_S = 0.2
"""How long the no-load voltages are averaged (CFS manual 4.2: relative to no load)."""
REST_BEFORE_TARE_S = 1.0
"""A/D idle at least this long between two blocks is a rest: the next block is preceded by
a new tare (shorter gaps keep the previous one, so a muscle still relaxing after a trial
is never taken as no load)."""


class AnalogSensor(Protocol):
    """What the A/D drivers, the tare and :func:`convert_block` use of a calibration: the
    six-axis sensor's analog outputs (:class:`AnalogCalibration`) or a dynamometer's torque
    output (:class:`nmsid.drivers.dynamometer.DynamometerCalibration`)."""

    @property
    def channels(self) -> dict[str, int]: ...
    @property
    def sync_channel(self) -> int | None: ...
    @property
    def monitor_channel(self) -> int | None: ...
    @property
    def sensor_span_V(self) -> tuple[float, float] | None: ...
    @property
    def n_channels(self) -> int: ...
    @property
    def full_wrench(self) -> bool: ...
    def wrench(self, volts: np.ndarray) -> np.ndarray: ...
    def force_N(self, wrench: np.ndarray) -> np.ndarray: ...
    def implausible(self) -> list[str]: ...


@dataclass(frozen=True)
class AnalogCalibration:
    """How voltages become a wrench. ``channels`` maps axis name -> A/D channel index."""

    channels: dict[str, int]
    rated: dict[str, float] = field(default_factory=dict)
    rated_output_V: dict[str, float] = field(default_factory=dict)
    offset_V: dict[str, float] = field(default_factory=dict)
    matrix: tuple[tuple[float, ...], ...] | None = None
    extension_direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    sync_channel: int | None = None
    monitor_channel: int | None = None
    sensor_span_V: tuple[float, float] | None = None
    """The sensor's output span, flagged as over-range at its edges (the hardware file
    gives :data:`SENSOR_SPAN_V` by default, ``sensor.output_span_V``); None: not checked."""

    def __post_init__(self):
        unknown = set(self.channels) - set(AXES)
        if unknown:
            raise ValueError(f"unknown sensor axes {sorted(unknown)}; valid: {list(AXES)}")
        if not any(a in self.channels for a in AXES[:3]):
            raise ValueError("at least one force axis (Fx, Fy, Fz) must be wired to the A/D")
        used = list(self.channels.values()) + [c for c in (self.sync_channel,
                                                           self.monitor_channel) if c is not None]
        if len(set(used)) != len(used):
            raise ValueError(f"A/D channels must be distinct, got {used}")
        if any(c < 0 for c in used):
            raise ValueError(f"A/D channels must be >= 0, got {used}")
        d = np.asarray(self.extension_direction, dtype=float)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
            raise ValueError("extension_direction must be 3 finite numbers, not all zero")
        for i, axis in enumerate(AXES[:3]):
            if d[i] != 0 and axis not in self.channels:
                raise ValueError(f"extension_direction uses {axis}, which is not wired to "
                                 "the A/D")
        if self.matrix is not None:
            m = np.asarray(self.matrix, dtype=float)
            if m.shape != (6, 6) or not np.isfinite(m).all():
                raise ValueError(f"matrix must be 6 x 6 finite numbers, got shape {m.shape}")
            if set(self.channels) != set(AXES):
                raise ValueError("a 6 x 6 matrix needs all six axes wired to the A/D")
        else:
            for axis in self.channels:
                r = self.rated.get(axis)
                v = self.rated_output_V.get(axis)
                if r is None or v is None or not (r > 0 and v > 0):
                    raise ValueError(f"axis {axis}: rated and rated_output_V must both be "
                                     f"> 0 (got {r!r}, {v!r})")

    @property
    def n_channels(self) -> int:
        """Channels the A/D must scan (0 .. highest used)."""
        used = list(self.channels.values())
        used += [c for c in (self.sync_channel, self.monitor_channel) if c is not None]
        return max(used) + 1

    @property
    def direction(self) -> np.ndarray:
        d = np.asarray(self.extension_direction, dtype=float)
        return d / np.linalg.norm(d)

    def volts_per_unit(self, axis: str) -> float:
        """Volts per N (or N m) of one axis (for fakes and probing)."""
        return self.rated_output_V[axis] / self.rated[axis]

    def wrench(self, volts: np.ndarray) -> np.ndarray:
        """(n, n_channels) volts -> (n, 6) wrench; axes not wired are 0."""
        volts = np.asarray(volts, dtype=float)
        out = np.zeros((volts.shape[0], 6))
        corrected = {a: volts[:, ch] - self.offset_V.get(a, 0.0)
                     for a, ch in self.channels.items()}
        if self.matrix is not None:
            v = np.column_stack([corrected[a] for a in AXES])
            out = v @ np.asarray(self.matrix, dtype=float).T
        else:
            for a, v in corrected.items():
                out[:, AXES.index(a)] = v * (self.rated[a] / self.rated_output_V[a])
        return out

    def implausible(self) -> list[str]:
        """Warnings (not errors) for a per-axis scaling the sensor cannot produce: with
        the outputs at 1.5 V at no load inside 0 .. 3.3 V (manual 4.1), a rated load cannot
        move an output by more than 1.8 V; the vendor's figure is 1 V."""
        out = []
        if self.matrix is None and self.sensor_span_V is not None:
            lo, hi = self.sensor_span_V
            room = max(hi - SENSOR_OFFSET_V, SENSOR_OFFSET_V - lo)
            for axis, v in self.rated_output_V.items():
                if v > room:
                    out.append(f"sensor.rated_output_V.{axis} = {v:g} V cannot be reached by "
                               f"an output spanning {lo:g} .. {hi:g} V; the Leptrino manual "
                               f"(4.1) gives {SENSOR_RATED_OUTPUT_V:g} V per rated load: forces "
                               f"would read {v / SENSOR_RATED_OUTPUT_V:g} times too small")
        return out

    def force_N(self, wrench: np.ndarray) -> np.ndarray:
        return wrench[:, :3] @ self.direction

    @property
    def full_wrench(self) -> bool:
        return set(self.channels) == set(AXES)


@dataclass(frozen=True, eq=False)
class ConvertedBlock:
    force_N: np.ndarray
    wrench: np.ndarray | None
    sync_V: np.ndarray | None
    saturated: bool
    monitor_V: np.ndarray | None = None


class NoLoadTare:
    """When an analog chain measures its no-load voltages, and the wrench they put out.

    ``due()`` is True before the first block (the session's start) and after a rest of
    :data:`REST_BEFORE_TARE_S`; :meth:`update` takes the volts of an untriggered
    :data:`TARE_WINDOW_S` window; :attr:`wrench` is then subtracted from every wrench
    (the same as using the measured voltages as ``offset_V``: the scaling is affine).
    """

    def __init__(self, *, rest_s: float = REST_BEFORE_TARE_S, window_s: float = TARE_WINDOW_S,
                 clock: Callable[[], float] = time.monotonic):
        self.rest_s, self.window_s, self.clock = rest_s, window_s, clock
        self.wrench = np.zeros(6)
        self.no_load_V: dict[str, float] = {}
        self.measured = False
        self._idle_since: float | None = None

    def due(self) -> bool:
        return not self.measured or (self._idle_since is not None and
                                     self.clock() - self._idle_since >= self.rest_s)

    def stopped(self) -> None:
        """A block ended: the A/D is idle from now."""
        self._idle_since = self.clock()

    def forget(self) -> None:
        """A new connection (reconnect): measure again before the next block."""
        self.measured = False

    def update(self, volts: np.ndarray, cal: AnalogSensor, device: str) -> None:
        """Take the mean of an untriggered window of volts (n, n_channels) as no load.

        Raises
        ------
        DeviceError
            No samples, or a sensor output at the edge of its span at rest (a wiring or
            supply fault: no tare could make its force right).
        """
        volts = np.asarray(volts, dtype=float).reshape(-1, cal.n_channels)
        if not len(volts):
            raise DeviceError(f"{device}: no samples for the no-load voltages (tare)")
        mean = volts.mean(axis=0)
        rest = {a: float(mean[ch]) for a, ch in cal.channels.items()}
        if cal.sensor_span_V is not None:
            lo, hi = cal.sensor_span_V
            edge = {a: v for a, v in rest.items()
                    if v <= lo + SPAN_EDGE_V or v >= hi - SPAN_EDGE_V}
            if edge:
                raise DeviceError(f"{device}: at rest the sensor outputs {edge} V, at the "
                                  f"edge of its {lo:g} .. {hi:g} V span (CFS manual 4.1): "
                                  "check its supply and wiring")
        self.wrench = cal.wrench(mean[None, :])[0]
        self.no_load_V, self.measured, self._idle_since = rest, True, None
        log.info("%s: no-load voltages %s V measured (tare %s)", device,
                 {a: round(v, 4) for a, v in rest.items()},
                 np.round(self.wrench, 3).tolist())


def measure_no_load(acq, device: str) -> None:
    """If ``acq``'s tare is due, measure the no-load voltages through its own blocks.

    ``acq`` is an A/D driver with ``cal``, ``fs_Hz``, ``_tare`` (:class:`NoLoadTare`),
    ``_capture`` (a list its conversion appends each block's volts to while not None),
    ``_start_block(n, triggered)``, ``read(timeout_s)`` and ``_stop_block()``: an
    untriggered window of :data:`TARE_WINDOW_S` before the trial's own block.
    """
    tare: NoLoadTare = acq._tare
    if not tare.due():
        return
    n = max(1, int(round(tare.window_s * acq.fs_Hz)))
    acq._capture = []
    flagged = ""
    try:
        acq._start_block(None, triggered=False)
        deadline = time.monotonic() + 2.0 + 4 * tare.window_s   # generous: a busy host
        while sum(len(v) for v in acq._capture) < n and time.monotonic() < deadline \
                and not flagged:
            chunk = acq.read(0.05)
            if chunk is not None and chunk.flags.any:
                flagged = chunk.flags.detail or "flagged"
        volts = np.concatenate(acq._capture) if acq._capture else \
            np.zeros((0, acq.cal.n_channels))
    finally:
        acq._capture = None
        acq._stop_block()
    if flagged:     # an A/D fault or a sensor at its span's edge: no tare from that
        raise DeviceError(f"{device}: the no-load voltages (tare) could not be measured: "
                          f"{flagged}")
    tare.update(volts[:n], acq.cal, device)


def convert_block(volts: np.ndarray, cal: AnalogSensor, range_V: float,
                  saturation_fraction: float = 0.995,
                  tare_wrench: np.ndarray | None = None) -> ConvertedBlock:
    """Interleaved-and-reshaped A/D volts (n, n_channels) -> force, wrench, sync, flags;
    ``tare_wrench`` (:attr:`NoLoadTare.wrench`) is subtracted from the wrench."""
    volts = np.asarray(volts, dtype=float).reshape(-1, cal.n_channels)
    wrench = cal.wrench(volts)
    if tare_wrench is not None:
        wrench = wrench - tare_wrench
    sensor_cols = list(cal.channels.values())
    sensor_V = volts[:, sensor_cols]
    saturated = bool(volts.size and np.abs(sensor_V).max() >= saturation_fraction * range_V)
    if volts.size and cal.sensor_span_V is not None:
        lo, hi = cal.sensor_span_V
        saturated = saturated or bool(sensor_V.min() <= lo + SPAN_EDGE_V
                                      or sensor_V.max() >= hi - SPAN_EDGE_V)
    sync = volts[:, cal.sync_channel].copy() if cal.sync_channel is not None else None
    monitor = volts[:, cal.monitor_channel].copy() if cal.monitor_channel is not None else None
    return ConvertedBlock(force_N=cal.force_N(wrench),
                          wrench=wrench if cal.full_wrench else None,
                          sync_V=sync, saturated=saturated, monitor_V=monitor)
