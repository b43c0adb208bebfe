"""Exceptions of the protocol designer (each subclasses a builtin; messages name the value)."""

from __future__ import annotations


class DesignError(ValueError):
    """A design setting or prior cannot be used (the message names it and what is valid)."""
