"""docs/settings.md holds the tables generated from the settings models (kept in step)."""

from __future__ import annotations

from pathlib import Path

from nmsid.analysis.settings import IdentificationSettings
from nmsid.drivers.hw_config import HardwareFile
from nmsid.protocols.config import Config
from nmsid.protocols.settings_base import settings_rows
from nmsid.study.config import StudyFile

DOC = Path(__file__).resolve().parents[2] / "docs" / "settings.md"
KINDS = [("Protocol file (`nmsid run --config`)", Config, ""),
         ("Hardware file (`--hw-config`)", HardwareFile, ""),
         ("Study file (`nmsid study STUDY.toml`)", StudyFile, ""),
         ("Identification settings (`[identification]` of a study file)",
          IdentificationSettings, "identification")]


def settings_tables() -> str:
    """The generated part of docs/settings.md."""
    out = []
    for title, cls, prefix in KINDS:
        out += [f"### {title}", "", "| key | default | bounds | why |", "|---|---|---|---|"]
        for key, default, bounds, why in settings_rows(cls, prefix):
            if cls is StudyFile and key.startswith("identification."):
                continue
            cells = [f"`{key}`", default.replace("|", "/"), bounds, why.replace("|", "/")]
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def test_docs_hold_the_generated_tables():
    text = DOC.read_text(encoding="utf-8")
    assert settings_tables() in text, ("docs/settings.md is out of date: paste "
                                       "tests/protocols/test_settings_docs.settings_tables()")
