"""Exceptions of the simulated rig.

Each subclasses a builtin (and, for device faults, the drivers' own exceptions) so that
the engine can catch a simulated fault exactly as it catches a real one, and the CLI turns
a user mistake into one line.
"""

from __future__ import annotations

from nmsid.drivers.errors import DeviceError


class SimConfigError(ValueError):
    """A virtual participant, effect, twin file or fault script setting is invalid.

    The message names the setting, the value and what would be valid.
    """


class StimulatorFault(DeviceError):
    """The (simulated) stimulator reports an error; nothing is loaded or started."""


class StimulatorDisconnected(StimulatorFault, ConnectionError):
    """The (simulated) stimulator is disconnected; call ``connect()`` once it is back."""


class DeviceStateError(RuntimeError):
    """A device call is not allowed in the device's present state (a programming error:
    e.g. ``start()`` before ``arm()``, ``read()`` before ``start()``)."""


__all__ = ["SimConfigError", "StimulatorFault", "StimulatorDisconnected", "DeviceStateError"]
