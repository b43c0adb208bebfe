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
A sample within ``saturation_fraction`` of the A/D range is flagged as over-range.

``monitor_channel`` (the dry run's only): the A/D input wired across the dummy-load
resistor (``nmsid probe --dry-run``); its volts are passed on unconverted, like the sync's.
A session's calibration has none.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


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


def convert_block(volts: np.ndarray, cal: AnalogCalibration, range_V: float,
                  saturation_fraction: float = 0.995) -> ConvertedBlock:
    """Interleaved-and-reshaped A/D volts (n, n_channels) -> force, wrench, sync, flags."""
    volts = np.asarray(volts, dtype=float).reshape(-1, cal.n_channels)
    wrench = cal.wrench(volts)
    sensor_cols = list(cal.channels.values())
    saturated = bool(volts.size and np.abs(volts[:, sensor_cols]).max()
                     >= saturation_fraction * range_V)
    sync = volts[:, cal.sync_channel].copy() if cal.sync_channel is not None else None
    monitor = volts[:, cal.monitor_channel].copy() if cal.monitor_channel is not None else None
    return ConvertedBlock(force_N=cal.force_N(wrench),
                          wrench=wrench if cal.full_wrench else None,
                          sync_V=sync, saturated=saturated, monitor_V=monitor)
