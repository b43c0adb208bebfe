"""Exceptions of the rig (engine, journal, GUI): each a branch of :mod:`nmsid.errors`."""

from __future__ import annotations

from nmsid.errors import MissingDependency, UserError


class RequestError(UserError):
    """What the operator asked for cannot be done as given (a missing file, a bad option or
    form field); the message names it and says what would be valid."""


class DisplayUnavailable(MissingDependency):
    """The operator window needs a screen and none is available."""
