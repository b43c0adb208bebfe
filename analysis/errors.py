"""Exceptions of the identification and model-selection module.

Every exception subclasses a branch of :mod:`nmsid.errors`; the ``nmsid`` command turns a
user error into one line.
Messages name the file, setting or value and say what would be valid.
"""

from __future__ import annotations

from nmsid.errors import UserError


class SettingError(UserError):
    """An identification setting has a value that cannot be used (message names it)."""


def setting_error(source: str, key: str, value, valid: str) -> SettingError:
    """The settings layer's factory (``protocols.settings_base``) for :class:`SettingError`."""
    return SettingError(f"{source}: {key} = {value!r} is not valid: {valid}")


class IdentificationError(UserError):
    """A level or session cannot be identified (no usable trial, too few samples, ...)."""


class TwinFileError(UserError):
    """A twin file is missing, unreadable or breaks ``docs/twin-file.md``."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class SimulateOptionError(SettingError):
    """An option of ``nmsid twin simulate`` is out of its bounds (message names the
    option, the value and the valid range)."""


class DataRangeError(UserError):
    """A session file holds values no rig can record (a force of 1e300 N, an infinite
    sample): the file is refused as a whole, naming the file, the trial and the value."""


class TwinInputError(UserError):
    """A twin cannot be run on the input given (a non-finite input, an sE where its curves
    give no valid dynamics); the message names the value and what would be valid."""
