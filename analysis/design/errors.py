"""Exceptions of the protocol designer (each a branch of :mod:`nmsid.errors`)."""

from __future__ import annotations

from nmsid.errors import UserError


class DesignError(UserError):
    """A design setting or prior cannot be used (the message names it and what is valid)."""
