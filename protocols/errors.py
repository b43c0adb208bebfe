"""Exceptions of the protocol layer; each subclasses a builtin and names what is wrong."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration value is refused (before anything is stimulated).

    Parameters
    ----------
    source : str
        Where the value came from (a TOML file path, ``"built-in defaults"``,
        ``"--seed"``, ...).
    setting : str
        Dotted name of the setting (``protocol.sE_levels``).
    value : object
        The refused value.
    valid : str
        What would be valid, in words.
    """

    def __init__(self, source: str, setting: str, value, valid: str):
        self.source = str(source)
        self.setting = setting
        self.value = value
        self.valid = valid
        super().__init__(f"{self.source}: setting {setting} = {value!r} is refused: {valid}")


class CalibrationError(ValueError):
    """A calibration ramp did not give usable Imin / Imax (or manual values are invalid)."""


class ScheduleError(ValueError):
    """A schedule cannot be built from the given levels / repeats / randomisation."""


class OutputPathError(ValueError):
    """An output path (``--out``) is refused: it exists (without ``--force``), is a
    session file, a dangling link or cannot be written. Raised before any work."""
