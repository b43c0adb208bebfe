"""Errors of the gap diagnosis (each a branch of :mod:`nmsid.errors`)."""

from __future__ import annotations

from nmsid.errors import UserError


class GapInputError(UserError):
    """A session (or twin file) cannot be diagnosed as given.

    The message names the file, the item and what would be valid.
    """
