"""One entry per stimulator kind: everything the rest of nmsid needs to know about it.

The hardware file's ``[stimulator] kind`` picks an entry of :data:`STIMULATORS`, the one
table of stimulator kinds; nothing else in nmsid branches on a device kind
(``tests/drivers/test_registry.py`` checks that no kind name appears outside this module
and the kind's own driver, settings and fake modules). An entry holds:

* ``title``: the device's name as people say it (``nmsid probe``, the GUI);
* ``settings``: the settings model of its ``[stimulator]`` table (its own module,
  ``drivers.<kind>_settings``), by which :mod:`nmsid.drivers.hw_config` validates it;
* ``make``: the driver, not connected, from those settings (and the fake bench's clock);
* ``install_fake``: the faithful fake put in place for ``fake = true`` (wired to the bench);
* ``load_library``: the vendor library loaded now, so a missing one is one line before any
  port is opened;
* ``report``: ``nmsid stimulation``'s figures of one level (what the device will deliver);
* ``dry_run``: what the dry run can check on a dummy load with this device.

The acquisition and E-stop kinds are dispatched here too: :data:`ACQUISITIONS` (settings
rules, driver, fake and its bench wiring, title, analog support) and :data:`ESTOPS`.

This module sits below :mod:`nmsid.drivers.hw_config` (which reads the file and validates
each table through these entries) and never imports it.

Adding a kind: docs/architecture.md, "Adding a stimulator kind" (and an acquisition kind).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from nmsid.drivers.analog_force import AnalogSensor
from nmsid.drivers.caio import CaioAcquisition, declare
from nmsid.drivers.dry_run import commanded_current_A
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.estop_switch import NidaqEStop, SerialEStop
from nmsid.drivers.fake_hardware import analog_wiring, load_fake
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.leptrino import LeptrinoAcquisition, LeptrinoSensor, _serial_module
from nmsid.drivers.nidaq import NidaqAcquisition, shared_pin
from nmsid.drivers.p24_settings import P24Config
from nmsid.drivers.rehamove3_settings import Rehamove3Config
from nmsid.drivers.rehastim2 import Rehastim2Stimulator
from nmsid.drivers.rehastim2_settings import Rehastim2Config
from nmsid.drivers.sciencemode4 import P24, REHAMOVE3, Sm4Model, Sm4Stimulator, to_steps_mA
from nmsid.drivers.sciencemode4_mid import Sm4MidLevelStimulator
from nmsid.drivers.stg4002 import DEFAULT_DLL, Stg4002Stimulator
from nmsid.drivers.stg4002_settings import Stg4002Config
from nmsid.drivers.stg_download import (
    STG4002_RANGE_NA,
    STG4002_RESOLUTION_NA,
    ChannelPlan,
    prepare_download,
)
from nmsid.drivers.stg_streaming import Stg4002WithStreaming, StgStreamingStimulator
from nmsid.drivers.stimulation_report import download_summary

if TYPE_CHECKING:  # annotations only: hw_config imports this module
    from nmsid.drivers.hw_config import HardwareConfig

LEPTRINO_MAX_RATE_HZ = 1200.0
"""What the Leptrino USB interface streams at (vendor sample: "maximum 1.2 kHz")."""


@dataclass(frozen=True)
class DryRunSupport:
    """What the dry run checks on a dummy load with this stimulator."""

    method: str
    """``lock-in``: the recorded current demodulated at the carrier and compared with the
    download; ``pulse-amplitude``: the recorded pulse peaks compared with the acknowledged
    pulse currents."""
    hardware_sync: bool
    """The device has a sync output the dry run can check goes low after a stop."""
    command_A: Callable[[Any, int, int, float], np.ndarray] | None = None
    """``command_A(stim, channel, n, fs_Hz)``: the current the device was given for the
    tested channel, as the monitor would see it (``lock-in`` only)."""


@dataclass(frozen=True)
class StimulatorKind:
    """One stimulator family (see the module docstring)."""

    kind: str
    title: str
    settings: type
    make: Callable[[Any, Callable[[], float] | None, Any], Any]
    """``make(settings, fake_clock or None, fake_stack or None) -> Stimulator``."""
    install_fake: Callable[[Any, Any], Any]
    """``install_fake(settings, bench) -> fake device`` (fake mode only)."""
    load_library: Callable[[Any], None]
    report: Callable[[Any, CheckedWaveform], dict]
    """``report(settings, checked) -> dict``: what one level delivers (``nmsid stimulation``)."""
    dry_run: DryRunSupport


# -- MCS STG4002 -----------------------------------------------------------------------------
def _make_stg(s: Stg4002Config, clock, stack):
    # download mode for calibration and identification trials; streaming mode (handed the
    # device by open_stream) for tracking trials: docs/hardware.md, "Streaming"
    common: dict[str, Any] = {"ceiling_ext_mA": s.ceiling_ext_mA,
                              "ceiling_flex_mA": s.ceiling_flex_mA,
                              "extensor_channel": s.extensor_channel,
                              "flexor_channel": s.flexor_channel, "sync_out": s.sync_out,
                              "serial": s.serial, "dll_path": s.dll_path or DEFAULT_DLL}
    return Stg4002WithStreaming(streaming=StgStreamingStimulator(clock=clock, **common),
                                output_rate_Hz=s.output_rate_Hz, clock=clock, **common)


def _fake_stg(s: Stg4002Config, bench):
    bench.sync_out = s.sync_out - 1
    mcs = load_fake("fake_mcs_usb")
    hw = mcs.FakeStgHardware(serial=s.serial or "4002-0001")
    mods = mcs.install(bench=bench, hardware=[hw])
    load_fake("fake_stg_streaming").install(mods)   # the same modules, the same device
    return hw


def _stg_library(stim) -> None:
    _ = stim.api   # the streaming class (same assembly) is loaded at the first stream


def _stg_command_A(stim: Stg4002Stimulator, channel: int, n: int, fs_Hz: float) -> np.ndarray:
    dl = stim.last_download   # the exact samples downloaded for the dry run's trial
    if dl is None:
        return np.zeros(n)
    return commanded_current_A(dl.channels[channel].expand(), dl.output_rate_Hz, n, fs_Hz)


def _stg_report(s: Stg4002Config, checked: CheckedWaveform) -> dict:
    ext = ChannelPlan(s.extensor_channel, "extensor", s.ceiling_ext_mA, STG4002_RANGE_NA,
                      STG4002_RESOLUTION_NA)
    flex = ChannelPlan(s.flexor_channel, "flexor", s.ceiling_flex_mA, STG4002_RANGE_NA,
                       STG4002_RESOLUTION_NA)
    return download_summary(prepare_download(checked, ext, flex, s.sync_out, s.output_rate_Hz))


# -- Hasomed RehaStim2 ----------------------------------------------------------------------
def _make_rs2(s: Rehastim2Config, clock, stack):
    fake = None if stack is None else stack.stimulator_fake
    return Rehastim2Stimulator(
        s.port, ceiling_ext_mA=s.ceiling_ext_mA, ceiling_flex_mA=s.ceiling_flex_mA,
        extensor_channel=s.extensor_channel, flexor_channel=s.flexor_channel,
        pulse_rate_Hz=s.pulse_rate_Hz, pulse_width_us=s.pulse_width_us,
        open_port=None if fake is None else fake.open,
        clock=clock, sleep=None if stack is None else stack.bench.sleep)


def _fake_rs2(s: Rehastim2Config, bench):
    dev = load_fake("fake_rehastim2").FakeRehastim2(clock=bench.now, sleep=bench.sleep)
    bench.stimulator = dev
    return dev


def _rs2_library(stim) -> None:
    _serial_module()


def _rs2_report(s: Rehastim2Config, checked: CheckedWaveform) -> dict:
    """The pulses of one level as the driver would send them (no device needed)."""
    n = int(np.floor(checked.duration_s * s.pulse_rate_Hz + 1e-9))
    k = np.minimum((np.arange(n) / s.pulse_rate_Hz * checked.fs_Hz + 1e-9).astype(np.int64),
                   checked.n_samples - 1)
    channels = {}
    for name, env, ch in (("extensor", checked.I_ext_mA, s.extensor_channel),
                          ("flexor", checked.I_flex_mA, s.flexor_channel)):
        amps = np.floor(np.asarray(env)[k] + 1e-9).astype(int)
        peak = int(amps.max(initial=0))
        channels[name] = {"name": name, "channel": ch, "pulses": int(n),
                          "peak_current_mA": float(peak),
                          "max_charge_per_phase_nC": float(peak * s.pulse_width_us),
                          "net_charge_per_trial_uC": 0.0,
                          "pulse_current_mA": amps.tolist()}
    return {"format": "nmsid-stimulation-1", "device": "rehastim2",
            "waveshape": {"kind": "biphasic_pulses", "pulse_rate_Hz": s.pulse_rate_Hz,
                          "pulse_width_us": s.pulse_width_us, "modulation": "amplitude"},
            "duration_s": float(checked.duration_s), "channels": channels}


# -- Hasomed P24 and RehaMove3 (ScienceMode4, low level) ---------------------------------------
def _sm4(model: Sm4Model):
    def make(s, clock, stack):
        fake = None if stack is None else stack.stimulator_fake
        driver = Sm4MidLevelStimulator if s.mode == "mid" else Sm4Stimulator
        return driver(
            s.port, model, ceiling_ext_mA=s.ceiling_ext_mA, ceiling_flex_mA=s.ceiling_flex_mA,
            extensor_channel=s.extensor_channel, flexor_channel=s.flexor_channel,
            pulse_rate_Hz=s.pulse_rate_Hz, pulse_width_us=s.pulse_width_us,
            interphase_us=s.interphase_us, open_port=None if fake is None else fake.open,
            clock=clock, sleep=None if stack is None else stack.bench.sleep)

    def install_fake(s, bench):
        dev = load_fake("fake_sciencemode4").FakeSm4(model.title.split()[-1], clock=bench.now)
        bench.stimulator = dev
        return dev

    def report(s, checked: CheckedWaveform) -> dict:
        """The pulses of one level as the driver would send them (no device needed)."""
        n = int(np.floor(checked.duration_s * s.pulse_rate_Hz + 1e-9))
        k = np.minimum((np.arange(n) / s.pulse_rate_Hz * checked.fs_Hz + 1e-9)
                       .astype(np.int64), checked.n_samples - 1)
        channels = {}
        for name, env, ch in (("extensor", checked.I_ext_mA, s.extensor_channel),
                              ("flexor", checked.I_flex_mA, s.flexor_channel)):
            amps = to_steps_mA(np.asarray(env)[k])
            peak = float(amps.max(initial=0.0))
            channels[name] = {"name": name, "channel": ch, "pulses": int(n),
                              "peak_current_mA": peak,
                              "max_charge_per_phase_nC": peak * s.pulse_width_us,
                              "net_charge_per_trial_uC": 0.0,
                              "pulse_current_mA": amps.tolist()}
        return {"format": "nmsid-stimulation-1", "device": s.kind,
                "waveshape": {"kind": "biphasic_pulses", "pulse_rate_Hz": s.pulse_rate_Hz,
                              "pulse_width_us": s.pulse_width_us,
                              "interphase_us": s.interphase_us, "modulation": "amplitude"},
                "duration_s": float(checked.duration_s), "channels": channels}

    return make, install_fake, report


_make_p24, _fake_p24, _p24_report = _sm4(P24)
_make_rm3, _fake_rm3, _rm3_report = _sm4(REHAMOVE3)


STIMULATORS: dict[str, StimulatorKind] = {
    "stg4002": StimulatorKind(
        kind="stg4002", title="MCS STG4002", settings=Stg4002Config, make=_make_stg,
        install_fake=_fake_stg, load_library=_stg_library, report=_stg_report,
        dry_run=DryRunSupport(method="lock-in", hardware_sync=True,
                              command_A=_stg_command_A)),
    "rehastim2": StimulatorKind(
        kind="rehastim2", title="Hasomed RehaStim2", settings=Rehastim2Config, make=_make_rs2,
        install_fake=_fake_rs2, load_library=_rs2_library, report=_rs2_report,
        dry_run=DryRunSupport(method="pulse-amplitude", hardware_sync=False)),
    "p24": StimulatorKind(
        kind="p24", title=P24.title, settings=P24Config, make=_make_p24,
        install_fake=_fake_p24, load_library=_rs2_library, report=_p24_report,
        dry_run=DryRunSupport(method="pulse-amplitude", hardware_sync=False)),
    "rehamove3": StimulatorKind(
        kind="rehamove3", title=REHAMOVE3.title, settings=Rehamove3Config, make=_make_rm3,
        install_fake=_fake_rm3, load_library=_rs2_library, report=_rm3_report,
        dry_run=DryRunSupport(method="pulse-amplitude", hardware_sync=False)),
}
"""Every stimulator kind nmsid drives, by ``[stimulator] kind``."""
DEFAULT_STIMULATOR = "stg4002"
"""The kind of a ``[stimulator]`` table without ``kind`` (files written before kinds)."""


def stimulator_kind(settings) -> StimulatorKind:
    """The registry entry of a validated ``[stimulator]`` table.

    Raises
    ------
    HardwareConfigError
        For a kind without an entry (a settings model added without its entry).
    """
    kind = settings.kind
    entry = STIMULATORS.get(kind)
    if entry is None or not isinstance(settings, entry.settings):
        raise HardwareConfigError(f"[stimulator] kind {kind!r}: "
                                  f"valid {', '.join(STIMULATORS)}")
    return entry


# -- acquisition kinds ------------------------------------------------------------------------
# ``[acquisition] kind`` picks an entry of ACQUISITIONS; its per-kind table
# ([acquisition.caio], [acquisition.nidaq], [acquisition.leptrino]) is read by its ``make``.
def _calibration(cfg: HardwareConfig) -> AnalogSensor:
    """An analog chain's calibration (``parse_hw_config`` makes one for every analog kind)."""
    if cfg.calibration is None:
        raise HardwareConfigError(f"{cfg.source}: acquisition.kind = "
                                  f"{cfg.acquisition.kind!r} has no [sensor] calibration")
    return cfg.calibration


def _make_caio(cfg: HardwareConfig, stack):
    a = cfg.acquisition
    lib = None
    if stack is not None:
        lib = declare(load_fake("fake_caio").FakeCaioLibrary(
            stack.bench, device_name=a.caio["device_name"],
            wiring=analog_wiring(cfg, stack.bench)))
    return CaioAcquisition(_calibration(cfg), lib=lib, **a.caio)


def _caio_library(acq) -> None:
    if isinstance(acq, CaioAcquisition):
        _ = acq.lib


def _make_nidaq(cfg: HardwareConfig, stack):
    return NidaqAcquisition(_calibration(cfg), **cfg.acquisition.nidaq)


def _fake_nidaqmx(cfg: HardwareConfig, stack) -> None:
    """The fake nidaqmx (one module for both users): the acquisition's analog inputs if it
    is the A/D, the E-stop's digital line if the E-stop is a DAQmx line."""
    analog = cfg.acquisition.kind == "nidaq"
    digital = cfg.estop.kind == "nidaq"
    load_fake("fake_nidaqmx").install(
        bench=stack.bench,
        devices={cfg.acquisition.nidaq["device"]: {"product_type": "USB-6212",
                                                   "serial_num": 0x1A2B3C}},
        wiring=analog_wiring(cfg, stack.bench) if analog else {},
        di_lines={cfg.estop.line: cfg.estop.released_level} if digital else {})


def _nidaq_library(acq) -> None:
    if isinstance(acq, NidaqAcquisition):
        _ = acq.api


def _check_nidaq_file(a, estop) -> tuple[str, object, str] | None:
    """The E-stop's DAQmx line must not be the acquisition's start-trigger pin."""
    if estop.kind != "nidaq":
        return None
    problem = shared_pin(estop.line, a.nidaq.start_trigger or f"/{a.nidaq.device}/PFI0")
    return ("estop.line", estop.line, problem) if problem else None


def _make_leptrino(cfg: HardwareConfig, stack):
    a = cfg.acquisition
    port = a.leptrino["port"] if stack is None else stack.emulator.port
    sensor = LeptrinoSensor(port, baudrate=a.leptrino["baudrate"])
    return LeptrinoAcquisition(sensor, extension_direction=cfg.extension_direction,
                               sync_on_external_input=a.leptrino["sync_on_external_input"])


def _fake_leptrino(cfg: HardwareConfig, stack) -> None:
    """A Leptrino emulator on a pseudo-terminal, its force from the bench (fake mode)."""
    bench = stack.bench
    d = np.asarray(cfg.extension_direction, float)
    d = d / np.linalg.norm(d)
    state = {"rate": 1200.0}

    def wrench(t):
        # the force at the record's own time (t s after the stream's start, by count), not
        # when a loaded host got round to writing it (a staircase of stale values)
        t_bench = (emu._t0 + t - bench._t0) * bench.speed
        f = float(bench.force_N(np.array([t_bench]), state["rate"])[0])
        return (*(f * d), 0.0, 0.0, 0.0)

    emu = load_fake("leptrino_emulator").LeptrinoEmulator(wrench_fn=wrench)
    emu.__enter__()
    stack.emulator = emu


def _leptrino_library(acq) -> None:
    _serial_module()


def _check_leptrino(a) -> tuple[str, object, str] | None:
    if a.fs_Hz > LEPTRINO_MAX_RATE_HZ:
        analog = " or ".join(f'"{k}"' for k, e in ACQUISITIONS.items() if e.analog)
        return ("fs_Hz", a.fs_Hz,
                f"the Leptrino USB interface streams at about {LEPTRINO_MAX_RATE_HZ:g} Hz and "
                f"cannot give {a.fs_Hz:g} Hz; use an analog chain (acquisition.kind = "
                f"{analog}) for the paper's 2000 Hz, or set acquisition.fs_Hz (and "
                f"the protocol's fs_Hz) to {LEPTRINO_MAX_RATE_HZ:g}")
    if not a.leptrino.port:
        return ("leptrino.port", "", "the serial port of the sensor is needed (COM5, "
                "/dev/ttyACM0)")
    return None


def _no_check(*_) -> tuple[str, object, str] | None:
    return None


@dataclass(frozen=True)
class AcquisitionKind:
    """One force acquisition chain, by ``[acquisition] kind``.

    ``check`` and ``check_file`` return ``(key, value, what is valid)`` for a bad setting
    (None if fine); :mod:`nmsid.drivers.hw_config` raises it in the file's one-line form.
    """

    kind: str
    title: str
    analog: bool
    """An A/D with spare inputs (the sensor's analog outputs, the sync, the dry run's
    monitor): ``[sensor]`` wiring and calibration apply, ``monitor_channel`` may be set."""
    load_library: Callable[[Any], None]
    make: Callable[[HardwareConfig, Any], Any]
    """``make(cfg, fake_stack or None) -> Acquisition``, not configured."""
    install_fake: Callable[[HardwareConfig, Any], None] | None
    """``install_fake(cfg, stack)``: the faithful fake in place and wired to the bench before
    any device is made (None: ``make`` builds its fake itself)."""
    check: Callable[[Any], tuple[str, object, str] | None] = _no_check
    """``check(acquisition_settings)``: per-kind rules; keys relative to ``[acquisition]``."""
    check_file: Callable[[Any, Any], tuple[str, object, str] | None] = _no_check
    """``check_file(acquisition_settings, estop)``: rules across tables; full keys."""


ACQUISITIONS: dict[str, AcquisitionKind] = {
    "caio": AcquisitionKind("caio", "Contec AI-1608AY-USB", True, _caio_library,
                            make=_make_caio, install_fake=None),
    "nidaq": AcquisitionKind("nidaq", "NI DAQ", True, _nidaq_library, make=_make_nidaq,
                             install_fake=_fake_nidaqmx, check_file=_check_nidaq_file),
    "leptrino": AcquisitionKind("leptrino", "Leptrino USB", False, _leptrino_library,
                                make=_make_leptrino, install_fake=_fake_leptrino,
                                check=_check_leptrino),
}
"""Every force acquisition chain nmsid reads, by ``[acquisition] kind`` (the members of
``hw_config.AcquisitionSettings.kind``; a test checks they agree)."""


def acquisition_kind(cfg: HardwareConfig) -> AcquisitionKind:
    """The registry entry of a validated hardware file's ``[acquisition]``."""
    return acquisition_entry(cfg.acquisition.kind)


def acquisition_entry(kind: str) -> AcquisitionKind:
    """The registry entry of an ``[acquisition] kind``.

    Raises
    ------
    HardwareConfigError
        For a kind without an entry (a kind added to the settings without its entry).
    """
    entry = ACQUISITIONS.get(kind)
    if entry is None:
        raise HardwareConfigError(f"[acquisition] kind {kind!r}: "
                                  f"valid {', '.join(ACQUISITIONS)}")
    return entry


# -- E-stop kinds -----------------------------------------------------------------------------
def _make_serial_estop(cfg: HardwareConfig, stack):
    return SerialEStop("loop://" if stack is not None else cfg.estop.port, line=cfg.estop.line)


def _make_nidaq_estop(cfg: HardwareConfig, stack):
    return NidaqEStop(cfg.estop.line, released_level=cfg.estop.released_level)


def _check_serial_estop(e) -> tuple[str, object, str] | None:
    if not e.port:
        return ("port", "", "the USB-serial adapter's port is needed")
    if e.line not in ("CTS", "DSR"):
        return ("line", e.line, "valid: CTS, DSR")
    return None


def _check_nidaq_estop(e) -> tuple[str, object, str] | None:
    if "/" not in e.line:
        return ("line", e.line, "a DAQmx digital line such as Dev1/port0/line0")
    return None


def _fake_nidaq_estop(cfg: HardwareConfig, stack) -> None:
    if acquisition_kind(cfg).install_fake is not _fake_nidaqmx:   # not installed already
        _fake_nidaqmx(cfg, stack)


@dataclass(frozen=True)
class EStopKind:
    """One hardware E-stop switch, by ``[estop] kind``."""

    kind: str
    make: Callable[[HardwareConfig, Any], Any]
    """``make(cfg, fake_stack or None) -> EStopSwitch or None`` (not opened)."""
    load_library: Callable[[], None]
    install_fake: Callable[[HardwareConfig, Any], None] | None = None
    check: Callable[[Any], tuple[str, object, str] | None] = _no_check
    """``check(estop_settings)``: per-kind rules; keys relative to ``[estop]``."""


ESTOPS: dict[str, EStopKind] = {
    "none": EStopKind("none", make=lambda cfg, stack: None, load_library=lambda: None),
    "serial": EStopKind("serial", make=_make_serial_estop, load_library=_serial_module,
                        check=_check_serial_estop),
    "nidaq": EStopKind("nidaq", make=_make_nidaq_estop, load_library=lambda: None,
                       install_fake=_fake_nidaq_estop, check=_check_nidaq_estop),
}
"""Every hardware E-stop switch, by ``[estop] kind`` (the members of
``hw_config.EStopConfig.kind``; a test checks they agree)."""


def estop_kind(cfg: HardwareConfig) -> EStopKind:
    """The registry entry of a validated hardware file's ``[estop]``."""
    return ESTOPS[cfg.estop.kind]
