"""Scriptable fault injection for the simulated rig.

A :class:`FaultScript` lists :class:`Fault` s, each at a time given either

* within a trial: ``trial=i, at_s=t`` - ``t`` seconds after the onset of the i-th trial
  (0-based; a *trial* is a stimulator run whose waveform delivers current on both channels,
  so calibration ramp steps, which stimulate one muscle, do not count; a re-run of an
  aborted trial counts as a new trial);
* within any stimulator run: ``run=i, at_s=t`` (ramp steps included, 0-based);
* in session time: ``session_s=t`` - clock time since the rig was made (virtual time on
  the fast clock).

The rig records when each fault took effect in ``FaultScript.fired``.

Examples
--------
>>> script = FaultScript([Fault(FaultKind.ESTOP, trial=2, at_s=7.5),
...                       Fault(FaultKind.FORCE_SPIKE, trial=0, at_s=6.0, amplitude_N=40.0)])
>>> len(script.faults)
2
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from nmsid.sim_backends.errors import SimConfigError


class FaultKind(enum.Enum):
    SENSOR_STALL = "sensor_stall"
    """No chunks arrive for ``duration_s`` (None: until the acquisition is stopped); the
    samples are buffered and delivered afterwards (a stalled stream, then a backlog), or,
    with ``lost_s``, the first ``lost_s`` of them never arrive (a dropout: the next chunk's
    ``start_index`` jumps and it carries ``flags.overrun``)."""
    SENSOR_FAULT = "sensor_fault"
    """Chunks over ``duration_s`` (default: the one chunk at the time) carry
    ``flags.sensor_fault``."""
    OVER_RANGE = "over_range"
    """Chunks over ``duration_s`` carry ``flags.over_range``."""
    OVERRUN = "overrun"
    """The chunk at the time carries ``flags.overrun``; ``lost_s`` of samples before it are
    lost (its ``start_index`` jumps)."""
    FORCE_SPIKE = "force_spike"
    """``amplitude_N`` is added to the reading for ``duration_s`` (default 2 ms)."""
    STIM_DISCONNECT = "stim_disconnect"
    """The stimulator is lost: output zero from then on, status ERROR, load / arm / start
    raise :class:`~nmsid.sim_backends.errors.StimulatorDisconnected` until ``connect()``."""
    STIM_ERROR = "stim_error"
    """The stimulator reports an error: output zero, status ERROR, load / arm / start raise
    :class:`~nmsid.sim_backends.errors.StimulatorFault` until ``connect()``."""
    ESTOP = "estop"
    """The hardware E-stop switch is pressed (and stays pressed until released)."""
    SENSOR_DISCONNECT = "sensor_disconnect"
    """A USB glitch of the force chain: from then on reads carry ``flags.sensor_fault``,
    ``start()`` raises and ``device_fault()`` names it, until ``reconnect()``, which fails
    while ``duration_s`` has not passed (None: the device is back at once)."""


SENSOR_KINDS = {FaultKind.SENSOR_STALL, FaultKind.SENSOR_FAULT, FaultKind.OVER_RANGE,
                FaultKind.OVERRUN, FaultKind.FORCE_SPIKE}
STIM_KINDS = {FaultKind.STIM_DISCONNECT, FaultKind.STIM_ERROR}


@dataclass(frozen=True)
class Fault:
    """One scheduled fault (give exactly one of ``trial``, ``run``, ``session_s``)."""

    kind: FaultKind
    trial: int | None = None
    run: int | None = None
    at_s: float = 0.0
    session_s: float | None = None
    duration_s: float | None = None
    amplitude_N: float = 100.0
    lost_s: float = 0.0
    detail: str = ""

    def __post_init__(self):
        try:
            object.__setattr__(self, "kind", FaultKind(getattr(self.kind, "value", self.kind)))
        except ValueError:
            raise SimConfigError(f"fault kind {self.kind!r} is unknown; valid: "
                                 f"{', '.join(k.value for k in FaultKind)}") from None
        given = [n for n in ("trial", "run", "session_s") if getattr(self, n) is not None]
        if len(given) != 1:
            raise SimConfigError(f"a fault needs exactly one of trial, run, session_s; got "
                                 f"{given or 'none'} for {self.kind.value}")
        for n in ("trial", "run"):
            v = getattr(self, n)
            if v is not None and (int(v) != v or v < 0):
                raise SimConfigError(f"fault {n} must be an integer >= 0, got {v!r}")
        for n in ("at_s", "session_s", "lost_s"):
            v = getattr(self, n)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise SimConfigError(f"fault {n} must be a finite number >= 0, got {v!r}")
        if self.duration_s is not None and not (math.isfinite(self.duration_s)
                                                and self.duration_s > 0):
            raise SimConfigError(f"fault duration_s must be > 0 or None, got "
                                 f"{self.duration_s!r}")
        if not math.isfinite(self.amplitude_N):
            raise SimConfigError(f"fault amplitude_N must be finite, got {self.amplitude_N!r}")

    def describe(self) -> str:
        where = (f"trial {self.trial} at {self.at_s:g} s" if self.trial is not None else
                 f"run {self.run} at {self.at_s:g} s" if self.run is not None else
                 f"session time {self.session_s:g} s")
        return f"{self.kind.value} at {where}"


@dataclass
class FiredFault:
    """A fault that took effect."""

    fault: Fault
    scheduled_clock_s: float
    """Clock time the script asked for."""
    sample_index: int | None
    """Absolute sample (rig time base) where it acted on the signals, if it did."""
    run_index: int | None
    """The stimulator run it fell in (None: none running)."""
    start_index: int | None = None
    """Sample index within that acquisition (ForceChunk.start_index space), if any."""


@dataclass
class FaultScript:
    """The faults a test scripts for one rig, and the log of those that fired."""

    faults: list[Fault] = field(default_factory=list)
    fired: list[FiredFault] = field(default_factory=list)

    def __post_init__(self):
        self.faults = [f if isinstance(f, Fault) else Fault(**f) for f in self.faults]

    def add(self, fault: Fault) -> FaultScript:
        self.faults.append(fault)
        return self

__all__ = ["FaultKind", "Fault", "FaultScript", "FiredFault", "SENSOR_KINDS", "STIM_KINDS"]
