"""Exceptions of the hardware drivers.

Every exception subclasses a branch of :mod:`nmsid.errors` (device faults, user errors,
missing libraries). Messages name the device, setting or library and say what would be
valid or how to fix it.
"""

from __future__ import annotations

from nmsid.drivers.interfaces import CurrentLimitError
from nmsid.errors import DeviceFault, MissingDependency, UserError


class VendorLibraryMissing(MissingDependency):
    """A vendor library (Python package, .NET assembly or shared library) is not installed.

    The message is one line: what is missing, what needs it and how to install it.
    ``name`` is left ``None`` on purpose so the CLI prints this message, not its generic
    pip hint.
    """

    def __init__(self, what: str, needed_for: str, how_to_install: str):
        super().__init__(f"{what} is not installed (needed for {needed_for}); "
                         f"{how_to_install}")
        self.what = what
        self.needed_for = needed_for
        self.how_to_install = how_to_install


class DeviceNotFound(DeviceFault):
    """The configured device is not connected, not powered, or its serial does not match."""


class DeviceError(DeviceFault):
    """A vendor call failed; the message names the call and the vendor's error text."""


class ProtocolError(DeviceFault):
    """A device answered outside its documented protocol (bad frame, NAK, error result)."""


class HardwareConfigError(UserError):
    """The hardware configuration file holds a missing, unknown or invalid setting."""


def hw_config_error(source: str, key: str, value, valid: str) -> HardwareConfigError:
    """The settings layer's factory (``protocols.settings_base``) for hardware files."""
    return HardwareConfigError(f"{source}: {key} = {value!r} is invalid; {valid}")


class DeviceRangeError(CurrentLimitError):
    """A configured or requested current ceiling exceeds what the device can deliver."""


class ChargeBalanceError(CurrentLimitError):
    """Rendered stimulation data would leave net charge in a carrier period (nothing sent)."""


class StimulatorSettingError(HardwareConfigError):
    """A stimulator setting (output rate, carrier, resolution) the device cannot honour."""


class DeviceMemoryError(DeviceError):
    """A trial does not fit the stimulator's per-channel or sync memory (nothing sent)."""


class StimulatorFault(DeviceError):
    """The stimulator reported a fault during output (overcurrent shutdown, early end,
    an E-stop during a download); output was stopped and the trial must be aborted."""


__all__ = ["VendorLibraryMissing", "DeviceNotFound", "DeviceError", "ProtocolError",
           "HardwareConfigError", "hw_config_error", "DeviceRangeError", "CurrentLimitError",
           "ChargeBalanceError", "StimulatorSettingError", "DeviceMemoryError",
           "StimulatorFault"]
