"""Exceptions of the hardware drivers.

Every exception subclasses a builtin so that the ``nmsid`` command turns it into one
line (``rig.cli`` catches ``ValueError``, ``OSError``, ``ImportError`` ...). Messages name
the device, setting or library and say what would be valid or how to fix it.
"""

from __future__ import annotations

from nmsid.drivers.interfaces import CurrentLimitError


class VendorLibraryMissing(ImportError):
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


class DeviceNotFound(OSError):
    """The configured device is not connected, not powered, or its serial does not match."""


class DeviceError(OSError):
    """A vendor call failed; the message names the call and the vendor's error text."""


class ProtocolError(OSError):
    """A device answered outside its documented protocol (bad frame, NAK, error result)."""


class HardwareConfigError(ValueError):
    """The hardware configuration file holds a missing, unknown or invalid setting."""


class DeviceRangeError(CurrentLimitError):
    """A configured or requested current ceiling exceeds what the device can deliver."""


__all__ = ["VendorLibraryMissing", "DeviceNotFound", "DeviceError", "ProtocolError",
           "HardwareConfigError", "DeviceRangeError", "CurrentLimitError"]
