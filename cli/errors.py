"""Exceptions of the command line: user errors (exit status 2) that name the option or file."""

from __future__ import annotations

from nmsid.errors import UserError


class UsageError(UserError):
    """Options that cannot be used together, or an option value outside what is valid."""


class InputFileError(UserError):
    """An input file given on the command line cannot be read as documented."""
