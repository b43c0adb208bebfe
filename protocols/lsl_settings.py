"""The ``[lsl]`` table of a session configuration: Lab Streaming Layer, off by default.

Part of :mod:`nmsid.protocols.config`. The one definition of the run's LSL settings: the
protocol file sets them, ``nmsid run --lsl`` / ``--lsl-record NAME`` set the same fields
(:meth:`LslConfig.with_command_line`); ``docs/lsl.md``.
"""

from __future__ import annotations

import re

from pydantic import StrictBool, StrictStr, model_validator

from nmsid.protocols.errors import ConfigError
from nmsid.protocols.settings_base import SettingProblem, bounded, settings_dataclass

MAX_RECORDED_STREAMS = 16
"""At most this many ``record`` entries (each one inlet held open for the whole run)."""
STREAM_PATTERN = re.compile(r"[^\x00-\x1f\x7f]{1,128}")
"""A stream name or type as LSL shows it: 1 .. 128 printable characters."""


@settings_dataclass(ConfigError, prefix="lsl")
class LslConfig:
    """What a run publishes on and records from LSL (``docs/lsl.md``)."""

    publish: StrictBool = False
    """Outlets for force, commanded currents and event markers (``--lsl``)."""
    record: tuple[StrictStr, ...] = bounded((), max_length=MAX_RECORDED_STREAMS, why=(
        "each recorded stream holds an inlet open and its data in memory for the whole run"))
    """Streams (by name or type: EMG, Markers, MoCap) recorded into the session file under
    ``/lsl`` with their clock offsets (``--lsl-record``)."""

    @model_validator(mode="after")
    def _names(self):
        for i, name in enumerate(self.record):
            if not STREAM_PATTERN.fullmatch(name):
                raise SettingProblem(f"record[{i}]", name, "an LSL stream name or type: 1 "
                                     "to 128 printable characters (EMG, Markers, MoCap)")
        return self

    @property
    def active(self) -> bool:
        return self.publish or bool(self.record)

    def with_command_line(self, publish: bool, record: list[str] | None) -> LslConfig:
        """These settings with ``nmsid run``'s ``--lsl`` (switches publishing on) and
        ``--lsl-record`` (replaces the file's ``record`` when given) applied."""
        if not publish and not record:
            return self
        return LslConfig(publish=self.publish or publish,
                         record=tuple(record) if record else self.record)
