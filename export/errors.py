"""Exceptions of the export package (each subclasses a builtin)."""

from __future__ import annotations


class ExportError(ValueError):
    """A session cannot be exported as asked; the message names the file and the reason."""
