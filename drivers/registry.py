"""One entry per stimulator kind: everything the rest of nmsid needs to know about it.

The hardware file's ``[stimulator] kind`` picks an entry of :data:`STIMULATORS`; nothing
else in nmsid branches on a device kind (``tests/drivers/test_registry.py`` checks that no
kind name appears outside this module, the settings union of :mod:`nmsid.drivers.hw_config`
and the kind's own driver and fake modules). An entry holds:

* ``settings``: the settings model of its ``[stimulator]`` table;
* ``make``: the driver, not connected, from those settings (and the fake bench's clock);
* ``install_fake``: the faithful fake put in place for ``fake = true`` (wired to the bench);
* ``load_library``: the vendor library loaded now, so a missing one is one line before any
  port is opened;
* ``report``: ``nmsid stimulation``'s figures of one level (what the device will deliver);
* ``dry_run``: what the dry run can check on a dummy load with this device.

The acquisition kind is dispatched in one place too: :data:`ACQUISITIONS`.

Adding a stimulator kind: docs/architecture.md, "Adding a stimulator kind".
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable
from typing import Any

import numpy as np

from nmsid.drivers.caio import CaioAcquisition
from nmsid.drivers.dry_run import commanded_current_A
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.hw_config import HardwareConfig, StimulatorConfig
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.leptrino import _serial_module
from nmsid.drivers.nidaq import NidaqAcquisition
from nmsid.drivers.rehastim2 import Rehastim2Stimulator
from nmsid.drivers.rehastim2_settings import Rehastim2Config
from nmsid.drivers.stg4002 import DEFAULT_DLL, Stg4002Stimulator
from nmsid.drivers.stg_download import (STG4002_RANGE_NA, STG4002_RESOLUTION_NA, ChannelPlan,
                                        prepare_download)
from nmsid.drivers.stg_streaming import Stg4002WithStreaming, StgStreamingStimulator
from nmsid.drivers.stimulation_report import download_summary


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
def _make_stg(s: StimulatorConfig, clock, stack):
    # download mode for calibration and identification trials; streaming mode (handed the
    # device by open_stream) for tracking trials: docs/hardware.md, "Streaming"
    common: dict[str, Any] = dict(ceiling_ext_mA=s.ceiling_ext_mA,
                                  ceiling_flex_mA=s.ceiling_flex_mA,
                                  extensor_channel=s.extensor_channel,
                                  flexor_channel=s.flexor_channel, sync_out=s.sync_out,
                                  serial=s.serial, dll_path=s.dll_path or DEFAULT_DLL)
    return Stg4002WithStreaming(streaming=StgStreamingStimulator(**common),
                                output_rate_Hz=s.output_rate_Hz, clock=clock, **common)


def _fake_stg(s: StimulatorConfig, bench):
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


def _stg_report(s: StimulatorConfig, checked: CheckedWaveform) -> dict:
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


STIMULATORS: dict[str, StimulatorKind] = {
    "stg4002": StimulatorKind(
        kind="stg4002", title="MCS STG4002", settings=StimulatorConfig, make=_make_stg,
        install_fake=_fake_stg, load_library=_stg_library, report=_stg_report,
        dry_run=DryRunSupport(method="lock-in", hardware_sync=True,
                              command_A=_stg_command_A)),
    "rehastim2": StimulatorKind(
        kind="rehastim2", title="Hasomed RehaStim2", settings=Rehastim2Config, make=_make_rs2,
        install_fake=_fake_rs2, load_library=_rs2_library, report=_rs2_report,
        dry_run=DryRunSupport(method="pulse-amplitude", hardware_sync=False)),
}
"""Every stimulator kind nmsid drives, by ``[stimulator] kind``."""


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
def _caio_library(acq) -> None:
    if isinstance(acq, CaioAcquisition):
        _ = acq.lib


def _nidaq_library(acq) -> None:
    if isinstance(acq, NidaqAcquisition):
        _ = acq.api


def _leptrino_library(acq) -> None:
    _serial_module()


@dataclass(frozen=True)
class AcquisitionKind:
    kind: str
    title: str
    analog: bool
    """An A/D with spare inputs (the dry run's monitor, a sync channel)."""
    load_library: Callable[[Any], None]


ACQUISITIONS: dict[str, AcquisitionKind] = {
    "caio": AcquisitionKind("caio", "Contec AI-1608AY-USB", True, _caio_library),
    "nidaq": AcquisitionKind("nidaq", "NI DAQ", True, _nidaq_library),
    "leptrino": AcquisitionKind("leptrino", "Leptrino USB", False, _leptrino_library),
}


def acquisition_kind(cfg: HardwareConfig) -> AcquisitionKind:
    return ACQUISITIONS[cfg.acquisition.kind]

