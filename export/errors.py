"""Exceptions of the export package (each a branch of :mod:`nmsid.errors`)."""

from __future__ import annotations

from nmsid.errors import UserError


class ExportError(UserError):
    """A session cannot be exported as asked; the message names the file and the reason."""


class FmuExportError(ExportError):
    """A twin cannot be exported as an FMU as asked (a form or effect the FMU does not
    model, an existing output file, no C compiler); the message names it."""
