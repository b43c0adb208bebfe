"""How the faithful fakes of the vendor libraries are loaded.

The fakes (package ``testing.fakes``, shipped with nmsid) stand in for McsUsbNet, CAIO,
nidaqmx and the Leptrino sensor so that ``nmsid probe`` and ``nmsid run --backend hw`` can
be exercised without hardware: set ``fake = true`` in the ``[rig]`` table of the hardware
configuration, or the environment variable ``NMSID_HW_FAKE=1``. Never use them with a
participant.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from nmsid.drivers.dynamometer import DynamometerCalibration
from nmsid.drivers.errors import HardwareConfigError

if TYPE_CHECKING:
    from nmsid.drivers.hw_config import HardwareConfig

#: The package that holds the fakes.
PACKAGE = "nmsid.testing.fakes"


def fake_requested(config_says: bool = False) -> bool:
    return config_says or os.environ.get("NMSID_HW_FAKE", "") not in ("", "0", "false")


def load_fake(module: str) -> ModuleType:
    """Import the fake ``module`` (``fake_mcs_usb``, ``fake_caio``, ...) of :data:`PACKAGE`."""
    return importlib.import_module(f"{PACKAGE}.{module}")


def analog_wiring(cfg: HardwareConfig, bench) -> dict:
    """Fake sensor outputs of an analog chain consistent with the configured calibration
    (fake mode only); the monitor input, if configured, carries the fake dummy load's
    voltage. ``{A/D channel: f(t, force_N) -> volts}``."""
    wiring = _sensor_wiring(cfg, bench)
    if cfg.acquisition.monitor_channel is not None:
        wiring[cfg.acquisition.monitor_channel] = load_fake("bench").monitor_wiring(bench)
    return wiring


def _sensor_wiring(cfg: HardwareConfig, bench) -> dict:
    cal = cfg.calibration
    if cal is None:     # parse_hw_config makes one for every analog chain
        raise HardwareConfigError(f"{cfg.source}: the fake analog wiring needs the [sensor] "
                                  "calibration of an analog chain")
    if isinstance(cal, DynamometerCalibration):   # the torque output, driven by torque
        return load_fake("bench").dynamometer_analog_wiring(
            bench, cal.channel, cal.Nm_per_V, sign=cal.sign, sync_channel=cal.sync_channel,
            span_V=cal.sensor_span_V or (-10.0, 10.0))
    d = cal.direction
    if cal.matrix is None:
        # the sensor per its manual, driven by force (not by the configured calibration)
        return load_fake("bench").leptrino_analog_wiring(
            bench, cal.channels, dict(cal.rated), direction=tuple(d),
            sync_channel=cal.sync_channel)
    minv = np.linalg.inv(np.asarray(cal.matrix, dtype=float))
    axes = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
    wiring: dict = {}
    for axis, ch in cal.channels.items():
        gain = float(minv[axes.index(axis), :3] @ d)
        off = cal.offset_V.get(axis, 0.0)
        wiring[ch] = lambda t, force, g=gain, o=off: force * g + o
    wiring[cal.sync_channel] = lambda t, force: bench.sync_V(t)
    return wiring
