"""Exceptions of the study package (each subclasses a builtin)."""

from __future__ import annotations


class StudyConfigError(ValueError):
    """A STUDY.toml or study folder is unusable; the message names the file and setting."""


def study_config_error(source: str, key: str, value, valid: str) -> StudyConfigError:
    """The settings layer's factory (``protocols.settings_base``) for study files."""
    return StudyConfigError(f"{source}: {key} = {value!r} is refused: {valid}")
