"""An isokinetic dynamometer's analog torque output on the rig's A/D: volts -> joint torque.

A knee or an ankle session measures the joint torque on a dynamometer (``docs/joints.md``);
the dynamometer's own software owns the motor, and its **analog torque output** is wired to
one input of the rig's A/D (Contec or NI, the same drivers as the six-axis sensor's analog
outputs, :mod:`nmsid.drivers.caio` / :mod:`nmsid.drivers.nidaq`), beside the stimulator's
sync output. What the driver needs to know is in the hardware file's
``[sensor.dynamometer]`` table (``sensor.kind = "dynamometer"``):

* ``channel``: the A/D input of the torque output;
* ``Nm_per_V``: the torque per volt of that output. Dynamometers make it a setting, not a
  constant: Biodex's EMG/Analog Signal Access utility "configures the scale factors and
  operating modes of the analog signal outputs for velocity, torque and position"
  (Biodex addendum FN 14-379, System 3 Rev 2 and System 4, chapter 1), so the lab copies
  the figure its dynamometer is set to;
* ``offset_V``: the nominal output at no torque; like the six-axis sensor's it is only
  nominal: the arm's and the limb's weight and the amplifier's offset move it, so the
  same **automatic tare** as the analog force chain (issue 37,
  :class:`nmsid.drivers.analog_force.NoLoadTare`) measures the output at rest before the
  session's first block and after each rest, and every torque the driver returns, the one
  the interlock's limit acts on, is relative to it;
* ``sign``: +1 if the dynamometer's positive torque is the joint's positive direction
  (the extensor channel's action: knee extension, plantarflexion), -1 otherwise;
* ``output_span_V``: the output's span, flagged as over-range at its edges (default
  -5 .. +5 V: "the analog signals for the Biodex range from -5 to +5 volts for Velocity
  and Torque", Noraxon's Biodex integration guide, "Setting up a Protocol and Scaling
  Analog Torque, Velocity, and Position Channels").

:class:`DynamometerCalibration` has the interface the A/D drivers, the tare and
:func:`~nmsid.drivers.analog_force.convert_block` use of
:class:`~nmsid.drivers.analog_force.AnalogCalibration` (``channels``, ``n_channels``,
``wrench``, ``force_N``, ...): the torque is carried in the wrench's moment about z (the
dynamometer's shaft) and returned as the session's ``force_N`` column, in N m
(``docs/joints.md``: the contract's name, the joint's unit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DYNAMOMETER_SPAN_V = (-5.0, 5.0)
"""Noraxon, Biodex integration guide: the torque output spans -5 .. +5 V."""
TORQUE_AXIS = "Mz"
"""The wrench column the torque is carried in (the moment about the dynamometer's shaft)."""


@dataclass(frozen=True)
class DynamometerCalibration:
    """How the dynamometer's torque output's volts become the joint torque (N m)."""

    channel: int
    Nm_per_V: float
    offset_V: float = 0.0
    sign: float = 1.0
    sync_channel: int | None = None
    monitor_channel: int | None = None
    sensor_span_V: tuple[float, float] | None = DYNAMOMETER_SPAN_V

    matrix = None
    """No cross-talk matrix (one output): the six-axis chain's field, for the fakes."""

    def __post_init__(self):
        if not (isinstance(self.channel, int) and self.channel >= 0):
            raise ValueError(f"dynamometer channel must be an A/D channel >= 0, got "
                             f"{self.channel!r}")
        if not (math.isfinite(self.Nm_per_V) and self.Nm_per_V > 0):
            raise ValueError(f"Nm_per_V must be > 0, got {self.Nm_per_V!r}")
        if not math.isfinite(self.offset_V):
            raise ValueError(f"offset_V must be finite, got {self.offset_V!r}")
        if self.sign not in (1.0, -1.0):
            raise ValueError(f"sign must be +1 or -1, got {self.sign!r}")
        used = [self.channel] + [c for c in (self.sync_channel, self.monitor_channel)
                                 if c is not None]
        if len(set(used)) != len(used) or any(c < 0 for c in used):
            raise ValueError(f"A/D channels must be distinct and >= 0, got {used}")
        if self.sensor_span_V is not None:
            lo, hi = self.sensor_span_V
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"output_span_V must be two finite volts, low < high, got "
                                 f"{self.sensor_span_V!r}")

    @property
    def channels(self) -> dict[str, int]:
        """``{"Mz": channel}``: the torque output, as the tare and the converter see it."""
        return {TORQUE_AXIS: self.channel}

    @property
    def n_channels(self) -> int:
        """Channels the A/D must scan (0 .. highest used)."""
        return max([self.channel] + [c for c in (self.sync_channel, self.monitor_channel)
                                     if c is not None]) + 1

    @property
    def full_wrench(self) -> bool:
        """A dynamometer gives one torque, never the six-axis wrench."""
        return False

    def volts_per_unit(self, axis: str = TORQUE_AXIS) -> float:
        """Volts per N m of the torque output (fakes and probing)."""
        return 1.0 / self.Nm_per_V

    def wrench(self, volts: np.ndarray) -> np.ndarray:
        """(n, n_channels) volts -> (n, 6), the joint torque (N m, the joint's positive
        direction positive) in the moment about z; the other columns 0."""
        volts = np.asarray(volts, dtype=float)
        out = np.zeros((volts.shape[0], 6))
        out[:, 5] = self.sign * (volts[:, self.channel] - self.offset_V) * self.Nm_per_V
        return out

    def force_N(self, wrench: np.ndarray) -> np.ndarray:
        """The measured column of the session (``force_N``): the joint torque, N m."""
        return wrench[:, 5].copy()

    def implausible(self) -> list[str]:
        """Warnings (not errors): a scale whose whole span is below 10 N m cannot measure
        a leg's evoked torque; one whose half span exceeds 2000 N m is far beyond any
        dynamometer's range (a V per N m typed the wrong way round)."""
        if self.sensor_span_V is None:
            return []
        half = 0.5 * (self.sensor_span_V[1] - self.sensor_span_V[0]) * self.Nm_per_V
        if half < 10.0:
            return [f"sensor.dynamometer.Nm_per_V = {self.Nm_per_V:g}: the output's span "
                    f"measures only +/-{half:g} N m (is it V per N m?)"]
        if half > 2000.0:
            return [f"sensor.dynamometer.Nm_per_V = {self.Nm_per_V:g}: the output's span "
                    f"would measure +/-{half:g} N m, beyond any dynamometer"]
        return []

    def __repr__(self) -> str:
        return (f"DynamometerCalibration(channel {self.channel}, {self.Nm_per_V:g} N m/V, "
                f"sign {self.sign:+g})")

