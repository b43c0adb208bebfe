"""What the engine needs from the hardware: small interfaces, shared by real and sim devices.

The engine talks only to these. ``sim_backends`` implements them over a virtual
participant; ``drivers.stg4002``, ``drivers.rehastim2``, ``drivers.caio``,
``drivers.nidaq``, ``drivers.leptrino`` and ``drivers.estop_switch`` implement them over
vendor libraries. Beyond the core :class:`Stimulator` and :class:`ForceAcquisition`, what a
device may offer is a small runtime-checkable capability Protocol (:class:`Describable`,
:class:`DeliveryReporting`, :class:`HostStreamedStimulator`,
:class:`RecoverableAcquisition`, :class:`SampleTiming`, :class:`ReportsSensorInfo`),
reached with ``isinstance``, never ``getattr``. :class:`StimulatorCapabilities` declares
what the device renders (:class:`Waveshape`), checked by :func:`check_deliverable`.

Time base: the stimulator's start is the trigger. An acquisition started with
``triggered=True`` waits for it, so sample index 0 of the acquisition is stimulation onset
(hardware trigger / sync line). A stimulator without a trigger output declares
``hardware_trigger=False``; the acquisition is then started by the host just before the
output starts, and the driver records the onset delay it observed.

Safety: a stimulator only accepts a :class:`CheckedWaveform`, whose constructor refuses any
sample above the ceiling it carries, so a waveform over its ceiling cannot exist. Drivers
check it once more against the device range just before sending.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from nmsid.errors import SafetyError


class CurrentLimitError(SafetyError, ValueError):
    """A stimulation current would exceed its ceiling (nothing was sent)."""


# -- stimulator ---------------------------------------------------------------------
SINE_CARRIER = "sine_carrier"
BIPHASIC_PULSES = "biphasic_pulses"


@dataclass(frozen=True)
class Waveshape:
    """What the device makes of a current envelope: the device-neutral description.

    A trial is always per-channel current envelopes (:class:`CheckedWaveform`); the
    waveshape says how the device renders them: a sine carrier at ``carrier_Hz`` whose
    amplitude follows the envelope (the STG4002), or charge-balanced biphasic pulses at
    ``pulse_rate_Hz`` of ``pulse_width_us`` per phase whose amplitude (or width) follows it
    (ScienceMode devices).
    """

    kind: str = SINE_CARRIER
    """:data:`SINE_CARRIER` or :data:`BIPHASIC_PULSES`."""
    carrier_Hz: float = 0.0
    """Sine carrier frequency (``SINE_CARRIER``); 0 when the protocol's carrier is used."""
    pulse_rate_Hz: float = 0.0
    pulse_width_us: float = 0.0
    """Width of each phase (``BIPHASIC_PULSES``)."""
    interphase_us: float = 0.0
    modulation: str = "amplitude"
    """``amplitude`` (the envelope sets each pulse's current) or ``width``."""

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items()
                if not (isinstance(v, float) and v == 0.0)}


@dataclass(frozen=True)
class StimulatorCapabilities:
    """What a stimulator can do, as reported by the device (or the simulator)."""

    n_channels: int
    max_current_mA: float
    """Largest carrier amplitude the device can deliver on a channel."""
    resolution_mA: float
    """Smallest current step of the device's DAC."""
    output_rate_Hz: float
    """Rate at which the device renders the envelope: DAC samples for a sine carrier
    (carrier included), pulses per second for a pulse stimulator."""
    model: str = ""
    serial: str = ""
    firmware: str = ""
    waveshape: Waveshape = field(default_factory=Waveshape)
    """How the device renders an envelope (see :class:`Waveshape`)."""
    hardware_trigger: bool = True
    """The device's start emits a trigger / sync edge the acquisition starts on. When
    False (RehaStim2: no trigger output in ScienceMode2), the acquisition is started by the
    host just before the output and the trial's ``stimulation_json`` records the delay."""


class DeliveryCheckError(CurrentLimitError):
    """A trial's stimulation is beyond what the device declares it can deliver."""


def check_deliverable(caps: StimulatorCapabilities, *, ceiling_ext_mA: float,
                      ceiling_flex_mA: float, carrier_Hz: float, envelope_fs_Hz: float,
                      highest_envelope_Hz: float = 0.0) -> list[str]:
    """Check a session's stimulation against the device's capabilities before any output.

    Ceilings above the device's range are refused; a sine carrier the device cannot render
    (output rate below twice the carrier) is refused only for a sine-carrier device (a
    pulse stimulator does not render the protocol's carrier); an envelope varying faster
    than half a pulse device's update rate is returned as a warning.

    Returns
    -------
    list of str
        Warnings (implausible, not forbidden).

    Raises
    ------
    DeliveryCheckError
        Naming the value and what the device allows.
    """
    name = caps.model or "the stimulator"
    for key, ceiling in (("ceiling_ext_mA", ceiling_ext_mA),
                         ("ceiling_flex_mA", ceiling_flex_mA)):
        if ceiling > caps.max_current_mA + 1e-9:
            raise DeliveryCheckError(f"{key} = {ceiling:g} mA exceeds what {name} delivers "
                                     f"({caps.max_current_mA:g} mA); nothing was sent")
    warnings: list[str] = []
    if caps.waveshape.kind == SINE_CARRIER:
        if caps.output_rate_Hz < 2 * carrier_Hz:
            raise DeliveryCheckError(f"carrier_Hz = {carrier_Hz:g} Hz is above half the "
                                     f"output rate of {name} ({caps.output_rate_Hz:g} Hz)")
    elif caps.waveshape.kind == BIPHASIC_PULSES:
        if highest_envelope_Hz > caps.output_rate_Hz / 2:
            warnings.append(f"the envelope varies up to {highest_envelope_Hz:g} Hz but "
                            f"{name} updates its pulses at {caps.output_rate_Hz:g} Hz: "
                            "components above half that rate are not delivered")
    else:
        raise DeliveryCheckError(f"{name} declares the unknown waveshape "
                                 f"{caps.waveshape.kind!r}")
    if not envelope_fs_Hz > 0:
        raise DeliveryCheckError(f"envelope rate {envelope_fs_Hz!r} Hz: expected > 0")
    if caps.resolution_mA >= 0.1:
        warnings.append(f"{name} sets currents in steps of {caps.resolution_mA:g} mA: it "
                        "delivers each envelope value rounded down to a step; the trial "
                        "records the envelope (I_ext_mA, I_flex_mA) and its stimulation_json "
                        "the currents delivered")
    return warnings


class StimulatorState(enum.Enum):
    DISCONNECTED = "disconnected"
    IDLE = "idle"
    LOADED = "loaded"
    ARMED = "armed"
    RUNNING = "running"
    STOPPED = "stopped"
    ERROR = "error"


@dataclass(frozen=True)
class StimulatorStatus:
    state: StimulatorState
    output_active: bool
    """True while any channel may be delivering current."""
    error: str = ""
    sample_index: int = -1
    """Envelope sample being rendered, when the device reports it (-1 if unknown)."""


@dataclass(frozen=True, eq=False)
class CheckedWaveform:
    """One trial's stimulation, proven within its current ceilings by construction.

    The carrier (a sine at ``carrier_Hz``) is rendered on the stimulator side; this holds
    its amplitude envelope per channel, sampled at ``fs_Hz``.

    Parameters
    ----------
    I_ext_mA, I_flex_mA : array_like
        Carrier amplitude envelopes of the extensor and flexor channels, mA, >= 0.
    fs_Hz : float
        Envelope sample rate.
    carrier_Hz : float
        Sine carrier frequency.
    ceiling_ext_mA, ceiling_flex_mA : float
        The ceilings this waveform was checked against.

    Raises
    ------
    CurrentLimitError
        If any sample is negative, not finite, or above its channel's ceiling.
    """

    I_ext_mA: np.ndarray
    I_flex_mA: np.ndarray
    fs_Hz: float
    carrier_Hz: float
    ceiling_ext_mA: float
    ceiling_flex_mA: float

    def __post_init__(self):
        for name, ceiling in (("I_ext_mA", self.ceiling_ext_mA),
                              ("I_flex_mA", self.ceiling_flex_mA)):
            arr = np.array(getattr(self, name), dtype=np.float64, copy=True)
            if arr.ndim != 1:
                raise CurrentLimitError(f"{name} must be 1-D, got shape {arr.shape}")
            if not np.isfinite(ceiling) or ceiling < 0:
                raise CurrentLimitError(f"ceiling for {name} must be a finite number >= 0, "
                                        f"got {ceiling!r}")
            if arr.size and not np.all(np.isfinite(arr)):
                raise CurrentLimitError(f"{name} holds non-finite samples (NaN or inf)")
            if arr.size and arr.min() < 0:
                raise CurrentLimitError(f"{name} holds negative amplitudes (min "
                                        f"{arr.min():.3f} mA); amplitudes must be >= 0")
            if arr.size and arr.max() > ceiling:
                k = int(np.argmax(arr))
                raise CurrentLimitError(
                    f"{name} sample {k} = {arr[k]:.3f} mA exceeds the ceiling "
                    f"{ceiling:.3f} mA; nothing was sent to the stimulator")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if len(self.I_ext_mA) != len(self.I_flex_mA):
            raise CurrentLimitError("I_ext_mA and I_flex_mA must have the same length, got "
                                    f"{len(self.I_ext_mA)} and {len(self.I_flex_mA)}")
        if not self.fs_Hz > 0:
            raise CurrentLimitError(f"fs_Hz must be > 0, got {self.fs_Hz!r}")

    @property
    def n_samples(self) -> int:
        return len(self.I_ext_mA)

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_Hz


@runtime_checkable
class Stimulator(Protocol):
    """A current-controlled stimulator with (at least) an extensor and a flexor channel."""

    def connect(self) -> None: ...

    def capabilities(self) -> StimulatorCapabilities: ...

    def load(self, waveform: CheckedWaveform) -> None:
        """Send one trial's waveform to the device (does not start it)."""

    def arm(self) -> None:
        """Make ready to start on :meth:`start`."""

    def start(self) -> None:
        """Start output (hardware-timed); emits the trigger / sync the acquisition uses."""

    def stop_now(self) -> None:
        """Output to zero immediately. Thread-safe, idempotent, never raises."""

    def status(self) -> StimulatorStatus: ...

    def disconnect(self) -> None: ...


@runtime_checkable
class HostStreamedStimulator(Protocol):
    """Capability: stimulation updated by the host while the output runs (closed loop).

    Implemented by the simulated stimulator, the STG4002 in streaming mode
    (``CStg200xStreamingNet``) and pulse stimulators (ScienceMode). The core
    :class:`Stimulator` methods still apply: :meth:`Stimulator.stop_now` ends a stream with
    output at zero, exactly as it ends a downloaded trial.

    Safety: :meth:`open_stream` fixes the ceilings for the whole stream; every
    :meth:`write_stream` is checked against them before anything reaches the device
    (:class:`CurrentLimitError`, nothing sent), so no streamed amplitude can exceed them.
    """

    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float,
                    update_Hz: float) -> float:
        """Prepare a stream of amplitude updates at ``update_Hz``; return the rate used."""

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        """Queue the next carrier (or pulse) amplitudes per channel, mA, one per update."""

    def stream_space(self) -> int:
        """Updates that can be queued now without blocking."""

    def close_stream(self) -> str | None:
        """End the stream after the queued updates, output to zero. Idempotent.

        Returns a one-line report of a fault found only at close (the STG4002: the device
        ran out of data and stopped after the host's last write, so part of what was
        written never played), or "" / None; ``run_block`` aborts the trial with it."""


@runtime_checkable
class PeriodSafeStop(Protocol):
    """Capability: an ordinary end or abort that never cuts a carrier period or pulse.

    The STG4002's save stop (``SendStop`` with ``STOP_OPTION_SAVESTOP``, McsUsbNet 5.3.15)
    lets the running carrier period finish, so no net charge is left on the tissue; the
    immediate stop (:meth:`Stimulator.stop_now`) may cut a biphasic period mid-phase and
    is kept for an E-stop or a fault. ``run_block`` uses this for an ordinary end or an
    operator's abort, and ``stop_now`` whenever the interlock is latched.
    """

    def stop_after_period(self) -> None:
        """Stop at the end of the running period (then at once if still running). Never
        raises."""


@runtime_checkable
class Describable(Protocol):
    """Capability: the device describes itself (model, serial, settings) for ``nmsid probe``."""

    def describe(self) -> dict: ...


@runtime_checkable
class DeliveryReporting(Protocol):
    """Capability: the stimulator reports what it was given to deliver in the last trial
    (plain JSON types; stored as the trial's optional ``stimulation_json``)."""

    def delivery_summary(self) -> dict | None: ...


# -- force acquisition --------------------------------------------------------------
@dataclass(frozen=True)
class AcquisitionFlags:
    overrun: bool = False
    """Samples were lost (buffer overflow)."""
    over_range: bool = False
    """The sensor or converter saturated."""
    sensor_fault: bool = False
    """The sensor or converter reported an error."""
    detail: str = ""

    @property
    def any(self) -> bool:
        return self.overrun or self.over_range or self.sensor_fault


@dataclass(frozen=True, eq=False)
class ForceChunk:
    """A block of consecutive samples from the force chain.

    ``start_index`` counts samples from the trigger (stimulation onset), so sample
    ``start_index + k`` was taken at ``(start_index + k) / fs_Hz`` s after onset.
    """

    start_index: int
    force_N: np.ndarray
    """Endpoint force along the extension axis, extension positive."""
    wrench: np.ndarray | None = None
    """(n, 6) Fx, Fy, Fz, Mx, My, Mz in the sensor frame, if the chain provides it."""
    sync: np.ndarray | None = None
    """The stimulator's sync line as recorded by the A/D, if wired."""
    flags: AcquisitionFlags = field(default_factory=AcquisitionFlags)
    monitor: np.ndarray | None = None
    """Volts across the dummy-load resistor (``nmsid probe --dry-run`` only), if scanned."""

    @property
    def n(self) -> int:
        return len(self.force_N)


@runtime_checkable
class ForceAcquisition(Protocol):
    """A hardware-timed force measurement chain (sensor + A/D)."""

    def configure(self, fs_Hz: float) -> float:
        """Set the sampling rate; return the rate the hardware will really use."""

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        """Start acquiring ``n_samples`` (None: until stopped). With ``triggered`` the
        first sample is taken at the stimulator's start trigger."""

    def read(self, timeout_s: float) -> ForceChunk | None:
        """The next chunk, or None if none arrived within ``timeout_s``."""

    def stop(self) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class RecoverableAcquisition(Protocol):
    """Capability every acquisition driver of nmsid has (sim, CAIO, NI, Leptrino): say
    whether its link is down, and reconnect it."""

    def device_fault(self) -> str:
        """Empty when the link is fine, else what is wrong (one line)."""

    def reconnect(self, fs_Hz: float) -> float:
        """Open the device again (new handle / task / port); return the rate used."""


@runtime_checkable
class SampleTiming(Protocol):
    """Capability: a multiplexed A/D reports each channel's delay after the clock edge."""

    def sample_delay_s(self, channel: int) -> float: ...


@runtime_checkable
class ReportsSensorInfo(Protocol):
    """Capability: a digital sensor's product information (model, serial, firmware, rate)
    as read from the device (the Leptrino); None until it was read."""

    info: Any


# -- emergency stop ----------------------------------------------------------------
@runtime_checkable
class EStopInput(Protocol):
    """A hardware emergency-stop switch read by the host. Fail-safe: a disconnected or
    unreadable switch reads as pressed."""

    def is_pressed(self) -> bool: ...

    def close(self) -> None: ...


# -- time ------------------------------------------------------------------------
@runtime_checkable
class Clock(Protocol):
    """The engine's notion of time: real (hardware, GUI) or as fast as possible (sim)."""

    def monotonic_s(self) -> float: ...

    def sleep(self, duration_s: float) -> None: ...


class RealClock:
    """Wall-clock time (``time.monotonic`` / ``time.sleep``)."""

    def monotonic_s(self) -> float:
        import time
        return time.monotonic()

    def sleep(self, duration_s: float) -> None:
        import time
        if duration_s > 0:
            time.sleep(duration_s)


@dataclass
class RigDevices:
    """The devices of one rig, as a backend builds them for the engine."""

    stimulator: Stimulator
    acquisition: ForceAcquisition
    estop: EStopInput | None
    clock: Clock
    backend: str
    """``sim`` or a description of the hardware chain (stored in the session file)."""
    extensor_channel: int = 1
    flexor_channel: int = 2

    def close(self) -> None:
        """Output to zero, then release every device (never raises)."""
        for step in (self.stimulator.stop_now, self.acquisition.stop,
                     self.acquisition.close, self.stimulator.disconnect,
                     *( [self.estop.close] if self.estop is not None else [])):
            try:
                step()
            except Exception:  # shutting down: keep going, output is already zero
                pass
