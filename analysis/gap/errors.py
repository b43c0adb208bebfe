"""Errors of the gap diagnosis (each subclasses a builtin so the CLI prints one line)."""

from __future__ import annotations


class GapInputError(ValueError):
    """A session (or twin file) cannot be diagnosed as given.

    The message names the file, the item and what would be valid.
    """
