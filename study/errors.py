"""Exceptions of the study package (each a branch of :mod:`nmsid.errors`)."""

from __future__ import annotations

from nmsid.errors import UserError


class StudyConfigError(UserError):
    """A STUDY.toml or study folder is unusable; the message names the file and setting."""


def study_config_error(source: str, key: str, value, valid: str) -> StudyConfigError:
    """The settings layer's factory (``protocols.settings_base``) for study files."""
    return StudyConfigError(f"{source}: {key} = {value!r} is refused: {valid}")
