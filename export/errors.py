"""Exceptions of the export package (each a branch of :mod:`nmsid.errors`)."""

from __future__ import annotations

from nmsid.errors import UserError


class ExportError(UserError):
    """A session cannot be exported as asked; the message names the file and the reason."""
