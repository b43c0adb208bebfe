"""The fake bench: one clock and one simple participant shared by the fake devices.

The fake stimulator (``fake_mcs_usb``, or ``fake_rehastim2`` for a RehaStim2: any object
with ``started_at``, ``envelope_at``, ``current_at`` and ``sync_at``, installed as
``bench.stimulator`` by the registry's fake) plays what it was given on this clock; the
fake A/D converters (``fake_caio``, ``fake_nidaqmx``) sample, on the same clock, the sync
line and the analog outputs of a fake force sensor whose force follows what the fake
stimulator really outputs: each channel's delivered current is demodulated (peak of |I|
over the last carrier period), mapped through a recruitment curve, and the extensor minus
flexor activation drives a second-order system (Kp, wn, zeta) plus sensor noise.

``speed`` > 1 runs the bench faster than wall time (the drivers get ``bench.now`` as
their clock), so a 15 s trial takes 15 / speed s of a test.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np


class ForceModel:
    """Endpoint force (N, extension positive) from the delivered carrier amplitudes."""

    def __init__(self, fs_Hz: float, *, Kp_N: float = 8.0, wn_rad_s: float = 14.0,
                 zeta: float = 0.8, I_min_mA=(2.0, 2.0), I_max_mA=(10.0, 10.0),
                 noise_N: float = 0.02, seed: int = 0):
        self.I_min = np.asarray(I_min_mA, float)
        self.I_max = np.asarray(I_max_mA, float)
        self.noise_N = noise_N
        self.rng = np.random.default_rng(seed)
        # bilinear (Tustin) discretisation of Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)
        c = 2.0 * fs_Hz
        a0 = c * c + 2 * zeta * wn_rad_s * c + wn_rad_s ** 2
        self.b = np.array([1.0, 2.0, 1.0]) * Kp_N * wn_rad_s ** 2 / a0
        self.a = np.array([1.0, (2 * wn_rad_s ** 2 - 2 * c * c) / a0,
                           (c * c - 2 * zeta * wn_rad_s * c + wn_rad_s ** 2) / a0])
        self.zi = np.zeros(2)

    def activation(self, I_mA: np.ndarray, muscle: int) -> np.ndarray:
        return np.clip((I_mA - self.I_min[muscle]) / (self.I_max[muscle] - self.I_min[muscle]),
                       0.0, 1.0)

    def step(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> np.ndarray:
        drive = self.activation(I_ext_mA, 0) - self.activation(I_flex_mA, 1)
        b0, b1, b2 = self.b
        _, a1, a2 = self.a
        z0, z1 = self.zi
        y = np.empty(len(drive))
        for k, x in enumerate(drive.tolist()):  # direct form II transposed
            out = b0 * x + z0
            z0 = b1 * x - a1 * out + z1
            z1 = b2 * x - a2 * out
            y[k] = out
        self.zi = np.array([z0, z1])
        return y + self.noise_N * self.rng.standard_normal(len(y))


class FakeBench:
    """Shared clock + wiring between the fake stimulator and the fake A/D."""

    def __init__(self, *, speed: float = 1.0, seed: int = 0, force_model=None,
                 sync_high_V: float = 3.3):
        self.speed = float(speed)
        self.seed = seed
        self._t0 = time.monotonic()
        self.lock = threading.RLock()
        self.stimulator = None          # the fake CStg200xDownloadNet that is connected
        self.force_model = force_model  # built by the A/D when it knows its rate
        self.sync_high_V = sync_high_V
        self.extensor_channel = 0        # 0-based STG channels the sensor "feels"
        self.flexor_channel = 1
        self.sync_out = 0
        self.dummy_load: tuple[int, float] | None = None
        """``(0-based STG channel, ohm)`` of the dry run's resistor, when one is wired."""

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.speed

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s / self.speed)

    # -- what the A/D sees ------------------------------------------------------------
    def trigger_time(self) -> float | None:
        """Bench time of the last sync rising edge (stimulation onset), if any."""
        stg = self.stimulator
        return None if stg is None else stg.started_at

    def envelopes_mA(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        stg = self.stimulator
        if stg is None:
            z = np.zeros(len(t))
            return z, z
        return (stg.envelope_at(self.extensor_channel, t) / 1e6,
                stg.envelope_at(self.flexor_channel, t) / 1e6)

    def sync_V(self, t: np.ndarray) -> np.ndarray:
        stg = self.stimulator
        if stg is None:
            return np.zeros(len(t))
        return stg.sync_at(self.sync_out, t) * self.sync_high_V

    def monitor_V(self, t: np.ndarray) -> np.ndarray:
        """Volts across the dummy load: the fake STG's output current there x the resistor."""
        stg = self.stimulator
        if stg is None or self.dummy_load is None:
            return np.zeros(len(t))
        channel, ohm = self.dummy_load
        return stg.current_at(channel, t) * 1e-9 * ohm

    def force_N(self, t: np.ndarray, fs_Hz: float) -> np.ndarray:
        """Force at consecutive sample times ``t`` (call in time order)."""
        with self.lock:
            if self.force_model is None:
                self.force_model = ForceModel(fs_Hz, seed=self.seed)
            I_ext, I_flex = self.envelopes_mA(t)
            return self.force_model.step(I_ext, I_flex)


LEPTRINO_OFFSET_V, LEPTRINO_RATED_OUTPUT_V, LEPTRINO_SPAN_V = 1.5, 1.0, (0.0, 3.3)
"""Leptrino CFS manual No.M000104, 4.1: outputs 0 .. 3.3 V, 1.5 V offset at no load, 1 V
change at rated load."""
LEPTRINO_REST_V = {"Fx": 1.580, "Fy": 1.532, "Fz": 1.532, "Mx": 1.532, "My": 1.532,
                   "Mz": 1.532}
"""Where the fake sensor's outputs REST: off the nominal 1.5 V, as the CFS manual's own
examples (4.2: no-load voltages of 1.532 and 1.580 V); the driver measures them (tare)."""


def leptrino_analog_wiring(bench: FakeBench, channels: dict, rated: dict,
                           direction=(1.0, 0.0, 0.0), sync_channel=None,
                           noise_V: float = 0.00005, seed: int = 1,
                           rest_V: dict | None = None) -> dict:
    """The Leptrino analog sensor as its manual describes it, driven by FORCE: each axis
    outputs ``rest + 1 V x load / rated`` clipped to 0 .. 3.3 V (manual 4.1), whatever
    calibration the driver was given (``rated`` is the sensor's rating); ``rest_V``: the
    no-load voltages (default :data:`LEPTRINO_REST_V`, off the nominal 1.5 V)."""
    rest = {**LEPTRINO_REST_V, **(rest_V or {})}
    inner = sensor_wiring(bench, channels,
                          {a: LEPTRINO_RATED_OUTPUT_V / rated[a] for a in channels},
                          offset_V={a: rest[a] for a in channels},
                          direction=direction, sync_channel=None, noise_V=noise_V, seed=seed)
    lo, hi = LEPTRINO_SPAN_V
    wiring: dict[int, Callable[..., np.ndarray]] = {
        ch: (lambda t, force, fn=fn: np.clip(fn(t, force), lo, hi))
              for ch, fn in inner.items()}
    if sync_channel is not None:
        wiring[sync_channel] = lambda t, force: bench.sync_V(t)
    return wiring


DYNAMOMETER_SPAN_V = (-5.0, 5.0)
"""Noraxon, Biodex integration guide ("Setting up a Protocol and Scaling Analog Torque,
Velocity, and Position Channels"): "the analog signals for the Biodex range from -5 to +5
volts for Velocity and Torque"."""
DYNAMOMETER_REST_V = 0.12
"""Where the fake dynamometer's torque output RESTS with the limb strapped in: off its
nominal 0 V (the arm's and the limb's weight, the amplifier's offset); the driver measures
it (tare)."""


def dynamometer_analog_wiring(bench: FakeBench, channel: int, Nm_per_V: float, *,
                              sign: float = 1.0, sync_channel=None,
                              rest_V: float = DYNAMOMETER_REST_V,
                              span_V=DYNAMOMETER_SPAN_V, noise_V: float = 0.0005,
                              seed: int = 1) -> dict:
    """A dynamometer's analog torque output, driven by TORQUE (the bench's ``force``, here
    N m): ``rest_V + sign x torque / Nm_per_V`` plus white noise, clipped to the output's
    span (-5 .. +5 V, the guide above), whatever offset the driver was configured with.
    The scale is the dynamometer's own setting (Biodex addendum FN 14-379, chapter 1: its
    utility "configures the scale factors ... of the analog signal outputs"), so the fake
    takes it as given. ``{A/D channel: fn(t, torque) -> volts}``."""
    rng = np.random.default_rng(seed)
    lo, hi = span_V

    def torque_out(t, torque):
        v = rest_V + sign * np.asarray(torque, dtype=float) / Nm_per_V
        if noise_V:
            v = v + rng.normal(0.0, noise_V, size=np.shape(v))
        return np.clip(v, lo, hi)

    wiring: dict[int, Callable[..., np.ndarray]] = {channel: torque_out}
    if sync_channel is not None:
        wiring[sync_channel] = lambda t, force: bench.sync_V(t)
    return wiring


def sensor_wiring(bench: FakeBench, channels: dict, volts_per_unit: dict, offset_V=None,
                  direction=(1.0, 0.0, 0.0), sync_channel=None, noise_V: float = 0.0,
                  seed: int = 1) -> dict:
    """A/D wiring of the fake sensor: ``{channel: fn(t, force_N) -> volts}``.

    The sensor frame force is ``force_N * direction`` (moments 0); each wired axis puts out
    ``value * volts_per_unit[axis] + offset_V[axis]``; the sync channel carries the fake
    stimulator's sync output.
    """
    axes = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    offset_V = offset_V or {}
    rng = np.random.default_rng(seed)
    wiring: dict[int, Callable[..., np.ndarray]] = {}
    for axis, ch in channels.items():
        i = axes.index(axis)
        comp = d[i] if i < 3 else 0.0

        o = offset_V.get(axis, 0.0)

        def fn(t, force, comp=comp, k=volts_per_unit[axis], o=o):
            return force * comp * k + o + noise_V * rng.standard_normal(len(t))
        wiring[ch] = fn
    if sync_channel is not None:
        wiring[sync_channel] = lambda t, force: bench.sync_V(t)
    return wiring


def monitor_wiring(bench: FakeBench, noise_V: float = 1e-3, seed: int = 2):
    """A/D wiring of the dry run's monitor input: the voltage across ``bench.dummy_load``
    (the fake STG's real output, sample by sample) plus ``noise_V`` rms input noise."""
    rng = np.random.default_rng(seed)

    def fn(t, force):
        return bench.monitor_V(t) + noise_V * rng.standard_normal(len(t))
    return fn
