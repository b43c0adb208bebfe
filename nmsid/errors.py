"""The exceptions of nmsid, in one hierarchy.

Every exception nmsid raises on purpose derives from :class:`NmsidError` and belongs to one
branch, which decides what the ``nmsid`` command does with it:

=====================  =============================================  =========
branch                 meaning                                        exit code
=====================  =============================================  =========
:class:`UserError`     a bad file, setting or value given by the      2
                       user (or a missing optional package); the
                       message names it and says what would be valid
:class:`DeviceFault`   a device is unreachable or failed              3
:class:`SafetyError`   a safety check refused (current above its      4
                       ceiling, interlock tripped)
=====================  =============================================  =========

Anything else reaching the command line is a bug: a traceback and exit code 1.
Each package's ``errors.py`` subclasses these branches (and, for compatibility with
``except ValueError`` / ``except OSError`` code, the matching builtin).
"""

from __future__ import annotations


class NmsidError(Exception):
    """Root of every exception nmsid raises on purpose."""

    exit_code = 1


class UserError(NmsidError, ValueError):
    """A bad file, setting or value: one line naming it and what would be valid."""

    exit_code = 2


class MissingDependency(UserError, ImportError):
    """An optional package, vendor library or system library is not installed.

    The message says what is missing, what needs it and how to install it.
    """


class InputFileMissing(UserError, FileNotFoundError):
    """A file the user named does not exist or cannot be read as the kind it should be."""


class OutputExistsError(UserError, FileExistsError):
    """An output the user did not ask to replace already exists (nothing was written)."""


class DeviceFault(NmsidError, OSError):
    """A device cannot be reached or reports a failure."""

    exit_code = 3


class SafetyError(NmsidError, RuntimeError):
    """A safety check refused an action (nothing was stimulated beyond it)."""

    exit_code = 4


EXIT_BUG = 1
EXIT_USER_ERROR = UserError.exit_code
EXIT_DEVICE_FAULT = DeviceFault.exit_code
EXIT_SAFETY = SafetyError.exit_code

__all__ = ["NmsidError", "UserError", "MissingDependency", "InputFileMissing",
           "OutputExistsError", "DeviceFault",
           "SafetyError",
           "EXIT_BUG", "EXIT_USER_ERROR", "EXIT_DEVICE_FAULT", "EXIT_SAFETY"]
