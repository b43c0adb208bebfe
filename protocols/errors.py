"""Exceptions of the protocol layer; user errors (:class:`nmsid.errors.UserError`) that name
what is wrong."""

from __future__ import annotations

import os

from nmsid.errors import UserError


class ConfigError(UserError):
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


class CalibrationError(UserError):
    """A calibration ramp did not give usable Imin / Imax (or manual values are invalid)."""


class ScheduleError(UserError):
    """A schedule cannot be built from the given levels / repeats / randomisation."""
class SessionFileError(UserError):
    """A session file is missing, unreadable or breaks the contract.

    The message names the file and the item, and says what would be valid.
    """

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class SessionExistsError(UserError, FileExistsError):
    """Refused to create a session file where a file already exists (never overwrite)."""

    def __init__(self, path: str | os.PathLike):
        self.path = str(path)
        super().__init__(
            f"{self.path}: a file already exists here; nmsid never overwrites a session "
            "file. Choose another --out path, or resume it with --resume.")




def _mb(n_bytes: float) -> str:
    return f"{n_bytes / 1e6:.2f} MB"


class DiskFullError(SessionFileError):
    """Not enough free space to write a session file (or its journal) safely.

    Raised before the write when the free space is known to be short, or when the
    system reports ENOSPC / EDQUOT; the file already on disk is never damaged by it.
    """

    def __init__(self, path: str | os.PathLike, need_bytes: int, free_bytes: int,
                 doing: str = "writing it"):
        self.need_bytes = int(need_bytes)
        self.free_bytes = int(free_bytes)
        folder = os.path.dirname(os.path.abspath(path))
        super().__init__(path, f"disk full: {doing} needs {_mb(need_bytes)} in {folder}, "
                               f"{_mb(free_bytes)} free; free some space, then "
                               "`nmsid recover` / `nmsid run --resume` the session")


class SessionWriteError(SessionFileError):
    """The system refused a write to a session file or its journal (not a full disk)."""


class SessionLockedError(SessionFileError):
    """Another process (alive) writes this session; only one writer per session."""

    def __init__(self, path: str | os.PathLike, holder: str):
        self.holder = holder
        super().__init__(path, f"is being written by {holder}; one writer per session: "
                               "wait for it to end (or stop it) and try again")


class OutputPathError(UserError):
    """An output path (``--out``) is refused: it exists (without ``--force``), is a
    session file, a dangling link or cannot be written. Raised before any work."""
