"""User errors of the control package (one line each, exit 2)."""

from __future__ import annotations

from nmsid.errors import UserError


class ControlDesignError(UserError):
    """A twin or a design setting does not allow a controller (says which and why)."""


class ControllerFileError(UserError):
    """A ``controller.json`` or a target CSV is unreadable or inconsistent."""


class TrackingReportError(UserError):
    """A session has no tracking trials to report on."""
