"""Exceptions of the study package (each subclasses a builtin)."""

from __future__ import annotations


class StudyConfigError(ValueError):
    """A STUDY.toml or study folder is unusable; the message names the file and setting."""
