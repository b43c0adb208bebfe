"""Build the rig's devices from the hardware configuration: ``make_hw_rig(path)``.

``nmsid run --backend hw --hw-config FILE`` calls :func:`make_hw_rig`; ``nmsid probe``
calls :func:`build_devices`. Devices are created but not connected (the engine connects the
stimulator and configures the acquisition in its set-up); the E-stop switch is opened at
once so that a wrong port fails before the session starts.

With ``fake = true`` in ``[rig]`` (or ``NMSID_HW_FAKE=1``) the same drivers run against the
faithful fakes of ``testing/fakes`` (McsUsbNet, CAIO, nidaqmx, a Leptrino emulator on
a pseudo-terminal, a ``loop://`` serial E-stop), coupled through a simulated force model.
For testing the software only: never with a participant.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.fake_hardware import fake_requested, load_fake
from nmsid.drivers.hw_config import HardwareConfig, load_hw_config
from nmsid.drivers.interfaces import RealClock, RigDevices, Stimulator
from nmsid.drivers.registry import ACQUISITIONS, acquisition_kind, estop_kind, stimulator_kind

log = logging.getLogger(__name__)


class BenchClock:
    """The fake bench's clock as a :class:`nmsid.drivers.interfaces.Clock` (fake mode only)."""

    def __init__(self, bench):
        self.bench = bench

    def monotonic_s(self) -> float:
        return self.bench.now()

    def sleep(self, duration_s: float) -> None:
        self.bench.sleep(duration_s)


@dataclass
class FakeStack:
    """What fake mode set up (kept alive with the devices; closed with them)."""

    bench: object
    emulator: Any = None
    """The Leptrino serial emulator of a fake Leptrino chain (closed with the stack)."""
    stimulator_fake: object = None
    """The fake stimulator device installed for the configured kind (registry)."""

    def close(self) -> None:
        if self.emulator is not None:
            self.emulator.close()
            self.emulator = None


class _OwningAcquisition:
    """Delegates to an acquisition and closes the fake stack after it.

    Made by :func:`_own` as a subclass naming each public attribute of the acquisition it
    wraps: Python >= 3.12 checks a runtime protocol (``Describable``, ``SampleTiming``,
    ``RecoverableAcquisition``, ...) with ``inspect.getattr_static``, which does not see
    ``__getattr__``, so a wrapper that only had ``__getattr__`` lost every capability.
    """

    def __init__(self, inner, stack: FakeStack):
        self._inner, self._stack = inner, stack

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def configure(self, fs_Hz):
        return self._inner.configure(fs_Hz)

    def start(self, n_samples=None, *, triggered=True):
        return self._inner.start(n_samples, triggered=triggered)

    def read(self, timeout_s):
        return self._inner.read(timeout_s)

    def stop(self):
        return self._inner.stop()

    def close(self):
        try:
            self._inner.close()
        finally:
            self._stack.close()


def make_hw_rig(hw_config_path, *,
                session_ceilings_mA: tuple[float, float] | None = None) -> RigDevices:
    """The devices of the rig described by ``hw_config_path`` (see docs/hardware.md).

    ``session_ceilings_mA``: the session's ``calibration.ceiling_ext_mA`` /
    ``ceiling_flex_mA``, checked against the hardware file's before any device is built
    (:func:`check_session_ceilings`).

    Raises
    ------
    HardwareConfigError, FileNotFoundError
        For a bad or missing configuration (one line naming the setting), or session
        ceilings above the hardware's.
    VendorLibraryMissing, DeviceNotFound
        When a device or its library is missing (also one line).
    """
    cfg = load_hw_config(hw_config_path)
    if session_ceilings_mA is not None:
        check_session_ceilings(cfg, *session_ceilings_mA)
    return build_devices(cfg)


def check_session_ceilings(cfg: HardwareConfig, ceiling_ext_mA: float,
                           ceiling_flex_mA: float) -> None:
    """Refuse a session whose ceilings are above the hardware file's: each trial's waveform
    would be refused by the driver (and trip) one after the other, so say it once, before
    anything, naming both settings.

    Raises
    ------
    HardwareConfigError
        One line: the two settings, their values and what to change.
    """
    s = cfg.stimulator
    for side, session, hw in (("ext", ceiling_ext_mA, s.ceiling_ext_mA),
                              ("flex", ceiling_flex_mA, s.ceiling_flex_mA)):
        if session > hw + 1e-9:
            raise HardwareConfigError(
                f"the session's calibration.ceiling_{side}_mA = {session:g} mA is above "
                f"stimulator.ceiling_{side}_mA = {hw:g} mA of {cfg.source}: every trial would "
                f"be refused; set calibration.ceiling_{side}_mA to at most {hw:g} in the "
                "session configuration (or raise the hardware ceiling, if the hardware and "
                "the ethics approval allow)")


def build_devices(cfg: HardwareConfig) -> RigDevices:
    cfg, stack, clock = prepare(cfg)
    s = cfg.stimulator
    stim = make_stimulator(cfg, stack, clock)
    acq = make_acquisition(cfg, stack)
    # load every vendor library now: a missing one is reported (one line) before any port
    # is opened or anything else is tried
    stimulator_kind(s).load_library(stim)
    load_acquisition_library(cfg, acq)
    estop_kind(cfg).load_library()
    estop = _estop(cfg, stack)
    if estop is None:
        log.warning("no hardware E-stop switch configured ([estop] kind = \"none\"): only "
                    "the software E-stop and the stimulator's power switch remain")
    else:
        try:
            estop.open()
        except Exception:
            acq.close()
            raise
    return RigDevices(stimulator=stim, acquisition=acq, estop=estop, clock=clock,
                      backend=cfg.describe(), extensor_channel=s.extensor_channel,
                      flexor_channel=s.flexor_channel)


def prepare(cfg: HardwareConfig):
    """``(cfg, fake stack or None, clock)``: fake mode set up if asked (``nmsid probe``
    builds each device on its own from these)."""
    fake = fake_requested(cfg.fake)
    if fake and not cfg.fake:
        cfg = _with_fake(cfg)
    stack = _install_fakes(cfg) if fake else None
    clock = BenchClock(stack.bench) if stack is not None else RealClock()
    return cfg, stack, clock


def with_monitor(cfg: HardwareConfig) -> HardwareConfig:
    """The configuration the dry run acquires with: the analog chain scanning
    ``acquisition.monitor_channel`` too, at ``acquisition.monitor_fs_Hz``.

    Raises
    ------
    HardwareConfigError
        If the chain has no analog input (Leptrino) or no monitor channel is configured.
    """
    a = cfg.acquisition
    if not acquisition_kind(cfg).analog:
        analog = " or ".join(k for k, e in ACQUISITIONS.items() if e.analog)
        raise HardwareConfigError(
            f"{cfg.source}: the dry run records the dummy-load resistor's voltage on a spare "
            f"A/D input, and acquisition.kind = {a.kind!r} has none; use an analog chain "
            f"({analog}) for the dry run, or check the resistor with an oscilloscope "
            "(docs/hardware.md, section 6)")
    if a.monitor_channel is None:
        raise HardwareConfigError(
            f"{cfg.source}: acquisition.monitor_channel is not set; wire the dummy-load "
            "resistor's voltage to a spare A/D input and name it there, e.g. "
            "[acquisition] monitor_channel = 7 (docs/hardware.md, section 6)")
    if cfg.calibration is None:  # an analog chain always has one (hw_config builds it)
        raise HardwareConfigError(f"{cfg.source}: the analog chain has no [sensor] "
                                  "calibration; the dry run needs one")
    cal = replace(cfg.calibration, monitor_channel=a.monitor_channel)
    return replace(cfg, calibration=cal, acquisition=replace(a, fs_Hz=a.monitor_fs_Hz))


def make_stimulator(cfg: HardwareConfig, stack: FakeStack | None, clock) -> Stimulator:
    """The configured kind's stimulator driver (not connected, library not loaded)."""
    return stimulator_kind(cfg.stimulator).make(
        cfg.stimulator, clock.monotonic_s if stack is not None else None, stack)


def load_stimulator_library(cfg: HardwareConfig, stim) -> None:
    """Load the stimulator's vendor library now (raises VendorLibraryMissing)."""
    stimulator_kind(cfg.stimulator).load_library(stim)


def make_acquisition(cfg: HardwareConfig, stack: FakeStack | None):
    """The configured force acquisition (not configured yet)."""
    return _own(acquisition_kind(cfg).make(cfg, stack), stack)


def load_acquisition_library(cfg: HardwareConfig, acq) -> None:
    """Load the acquisition's vendor library now (raises VendorLibraryMissing)."""
    inner = acq._inner if isinstance(acq, _OwningAcquisition) else acq
    acquisition_kind(cfg).load_library(inner)


def make_estop(cfg: HardwareConfig, stack: FakeStack | None):
    """The configured E-stop switch, opened (None if none is configured)."""
    estop_kind(cfg).load_library()
    estop = _estop(cfg, stack)
    if estop is not None:
        estop.open()
    return estop


def _with_fake(cfg: HardwareConfig) -> HardwareConfig:
    return replace(cfg, fake=True)


def _forward(name: str) -> property:
    return property(lambda self: getattr(self._inner, name),
                    lambda self, value: setattr(self._inner, name, value))


def _own(acq, stack):
    if stack is None:
        return acq
    names = [n for n in dir(acq) if not n.startswith("_") and n not in vars(_OwningAcquisition)]
    cls = type(f"Owning{type(acq).__name__}", (_OwningAcquisition,),
               {n: _forward(n) for n in names})
    return cls(acq, stack)


def _estop(cfg: HardwareConfig, stack: FakeStack | None):
    return estop_kind(cfg).make(cfg, stack)


# -- fake mode ---------------------------------------------------------------------------
def _install_fakes(cfg: HardwareConfig) -> FakeStack:
    """Put the fake vendor modules in place and wire the fake bench (fake mode only)."""
    log.warning("FAKE hardware: %s runs against the fakes in testing/fakes, "
                "no device is used", cfg.source)
    bench = load_fake("bench").FakeBench(speed=cfg.fake_speed)
    s = cfg.stimulator
    bench.extensor_channel = s.extensor_channel - 1
    bench.flexor_channel = s.flexor_channel - 1
    stack = FakeStack(bench=bench, stimulator_fake=stimulator_kind(s).install_fake(s, bench))
    # each kind's fake in place and wired to the bench before any device is made
    for install in (acquisition_kind(cfg).install_fake, estop_kind(cfg).install_fake):
        if install is not None:
            install(cfg, stack)
    return stack
