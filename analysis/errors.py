"""Exceptions of the identification and model-selection module.

Every exception subclasses a builtin so that the ``nmsid`` command turns it into one line.
Messages name the file, setting or value and say what would be valid.
"""

from __future__ import annotations


class SettingError(ValueError):
    """An identification setting has a value that cannot be used (message names it)."""


def setting_error(source: str, key: str, value, valid: str) -> SettingError:
    """The settings layer's factory (``protocols.settings_base``) for :class:`SettingError`."""
    return SettingError(f"{source}: {key} = {value!r} is not valid: {valid}")


class IdentificationError(ValueError):
    """A level or session cannot be identified (no usable trial, too few samples, ...)."""


class TwinFileError(ValueError):
    """A twin file is missing, unreadable or breaks ``docs/twin-file.md``."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
