"""Errors of the physiological (muscle) twin."""

from __future__ import annotations

from nmsid.analysis.gap.errors import GapInputError


class MuscleFitError(GapInputError):
    """The muscle twin cannot be fitted as asked (a setting or the session does not suit it).

    The message names the setting or file and what would be valid.
    """
