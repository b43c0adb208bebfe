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

import dataclasses
import glob
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from nmsid.analysis.settings import IdentificationSettings
from nmsid.study.errors import StudyConfigError

SETTING_DEFAULTS = {"gap": True, "gap_max_sessions": 0, "figures": True}


@dataclass
class StudyConfig:
    """A resolved study: absolute session paths plus settings."""

    sessions: list[Path]
    participants: dict[str, str] = field(default_factory=dict)
    """Session file stem -> participant code used in the group analysis."""
    gap: bool = True
    gap_max_sessions: int = 0
    figures: bool = True
    identification: dict = field(default_factory=dict)
    source: str = ""

    def gap_sessions(self) -> set[Path]:
        """The sessions that get a gap diagnosis."""
        if not self.gap:
            return set()
        chosen = self.sessions if self.gap_max_sessions <= 0 else \
            self.sessions[:self.gap_max_sessions]
        return set(chosen)

    def identification_settings(self):
        """The ``IdentificationSettings`` with this study's overrides."""
        names = {f.name for f in dataclasses.fields(IdentificationSettings)}
        unknown = sorted(set(self.identification) - names)
        if unknown:
            raise StudyConfigError(f"{self.source}: [identification] has unknown setting(s) "
                                   f"{unknown}; valid: {sorted(names)}")
        return IdentificationSettings(**self.identification)


def load_study(source: str | Path) -> StudyConfig:
    """Read a STUDY.toml or list a folder of session files.

    Raises
    ------
    StudyConfigError
        If the file or folder is missing, the TOML is invalid, a setting is unknown or no
        session file is found.
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
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise StudyConfigError(f"{path}: not valid TOML ({exc})") from None
    unknown = sorted(set(data) - {"sessions", "participants", "settings", "identification"})
    if unknown:
        raise StudyConfigError(f"{path}: unknown key(s) {unknown}; valid: sessions, "
                               "participants, settings, identification")
    patterns = data.get("sessions")
    if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        raise StudyConfigError(f"{path}: 'sessions' must be a list of paths or globs, "
                               f"got {patterns!r}")
    base = path.parent
    sessions: list[Path] = []
    for pattern in patterns:
        full = pattern if Path(pattern).is_absolute() else str(base / pattern)
        hits = sorted(glob.glob(full, recursive=True))
        if not hits:
            raise StudyConfigError(f"{path}: sessions entry {pattern!r} matches no file")
        for h in hits:
            p = Path(h).resolve()
            if p not in sessions:
                sessions.append(p)
    settings = data.get("settings", {})
    bad = sorted(set(settings) - set(SETTING_DEFAULTS))
    if bad:
        raise StudyConfigError(f"{path}: [settings] has unknown key(s) {bad}; valid: "
                               f"{sorted(SETTING_DEFAULTS)}")
    merged = {**SETTING_DEFAULTS, **settings}
    for key, default in SETTING_DEFAULTS.items():
        if type(merged[key]) is not type(default):
            raise StudyConfigError(f"{path}: [settings] {key} = {merged[key]!r} must be "
                                   f"{type(default).__name__}")
    participants = data.get("participants", {})
    if not all(isinstance(v, str) for v in participants.values()):
        raise StudyConfigError(f"{path}: [participants] values must be participant codes")
    return StudyConfig(sessions=sessions, participants=dict(participants),
                       identification=dict(data.get("identification", {})),
                       source=str(path), **merged)
