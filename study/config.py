"""What a study is: its session files, participant overrides and settings.

A study is a folder of session files (every ``*.h5`` in it, recursively) or a TOML file::

    # STUDY.toml (paths and globs relative to this file)
    sessions = ["site-a/*.h5", "site-b/P07-20260301T090000Z.h5"]

    [participants]            # optional: file name (stem) -> participant code
    "P07-20260301T090000Z" = "P07"

    [settings]                # optional
    gap = true                # gap diagnosis per session (~10 s each)
    gap_max_sessions = 0      # diagnose only the first N sessions (0 = all)
    figures = true            # Figures 4-6 in the report

    [identification]          # optional: any IdentificationSettings field
    lowpass_Hz = 25.0
"""

from __future__ import annotations

import glob
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, Field, StrictBool, StrictInt, StrictStr

from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.config import PARTICIPANT_PATTERN
from nmsid.protocols.settings_base import (
    SettingProblem,
    bounded,
    read_toml,
    settings_dataclass,
    validate_settings,
)
from nmsid.study.errors import StudyConfigError, study_config_error

MAX_SESSION_ENTRIES = 100_000
"""Entries of ``sessions`` at most (each a path or a glob)."""


def _code(value: str) -> str:
    if not PARTICIPANT_PATTERN.fullmatch(value):
        raise SettingProblem("", value, "a participant code: 1 to 64 letters, digits, '_' "
                             "or '-' (no spaces or control characters)")
    return value


def _path_text(value: str) -> str:
    if not value or any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise SettingProblem("", value, "a path or glob without control characters")
    return value


@settings_dataclass(study_config_error, prefix="settings")
class StudySettings:
    """The ``[settings]`` table of a STUDY.toml."""

    gap: StrictBool = True
    """Gap diagnosis per session (~10 s each)."""
    gap_max_sessions: StrictInt = bounded(0, ge=0, le=MAX_SESSION_ENTRIES, why=(
        "diagnose only the first N sessions; 0 = all"))
    figures: StrictBool = True
    """Figures 4-6 in the report."""


@settings_dataclass(study_config_error)
class StudyFile:
    """The layout of a STUDY.toml (validated before any session is opened)."""

    sessions: list[Annotated[StrictStr, AfterValidator(_path_text)]] = bounded(
        min_length=1, max_length=MAX_SESSION_ENTRIES, why="paths or globs of session files")
    participants: dict[StrictStr, Annotated[StrictStr, AfterValidator(_code)]] = Field(
        default_factory=dict)
    settings: StudySettings = Field(default_factory=StudySettings)
    identification: IdentificationSettings = Field(default_factory=IdentificationSettings)


@settings_dataclass(study_config_error, frozen=False)
class StudyConfig:
    """A resolved study: absolute session paths plus settings."""

    sessions: list[Path]
    participants: dict[str, str] = Field(default_factory=dict)
    """Session file stem -> participant code used in the group analysis."""
    gap: StrictBool = True
    gap_max_sessions: StrictInt = bounded(0, ge=0, le=MAX_SESSION_ENTRIES, why=(
        "diagnose only the first N sessions; 0 = all"))
    figures: StrictBool = True
    identification: dict = Field(default_factory=dict)
    """Overrides of :class:`~nmsid.analysis.settings.IdentificationSettings` fields."""
    source: str = ""

    def gap_sessions(self) -> set[Path]:
        """The sessions that get a gap diagnosis."""
        if not self.gap:
            return set()
        chosen = self.sessions if self.gap_max_sessions <= 0 else \
            self.sessions[:self.gap_max_sessions]
        return set(chosen)

    def identification_settings(self) -> IdentificationSettings:
        """The ``IdentificationSettings`` with this study's overrides.

        Raises
        ------
        StudyConfigError
            Naming the study file and ``identification.<key>``.
        """
        return validate_settings(IdentificationSettings, self.identification,
                                 source=self.source, make_error=study_config_error,
                                 prefix="identification")


def load_study(source: str | Path) -> StudyConfig:
    """Read a STUDY.toml or list a folder of session files.

    Raises
    ------
    StudyConfigError
        If the file or folder is missing, the TOML is invalid, a setting is unknown or out
        of bounds, or no session file is found.
    """
    src = Path(source)
    if src.is_dir():
        sessions = sorted(p.resolve() for p in src.rglob("*.h5"))
        cfg = StudyConfig(sessions=sessions, source=str(src))
    elif src.is_file():
        cfg = _from_toml(src)
    else:
        raise StudyConfigError(f"{src}: no such study file or folder (give a STUDY.toml or "
                               "a folder of .h5 session files)")
    if not cfg.sessions:
        raise StudyConfigError(f"{src}: no session files (*.h5) found")
    return cfg


def _from_toml(path: Path) -> StudyConfig:
    data = read_toml(path, study_config_error, what="study file")
    spec = validate_settings(StudyFile, data, source=str(path), make_error=study_config_error)
    base = path.parent
    sessions: list[Path] = []
    for pattern in spec.sessions:
        full = pattern if Path(pattern).is_absolute() else str(base / pattern)
        hits = sorted(glob.glob(full, recursive=True))
        if not hits:
            raise StudyConfigError(f"{path}: sessions entry {pattern!r} matches no file")
        for h in hits:
            p = Path(h).resolve()
            if p not in sessions:
                sessions.append(p)
    return StudyConfig(sessions=sessions, participants=dict(spec.participants),
                       gap=spec.settings.gap, gap_max_sessions=spec.settings.gap_max_sessions,
                       figures=spec.settings.figures,
                       identification=dict(data.get("identification", {})), source=str(path))
