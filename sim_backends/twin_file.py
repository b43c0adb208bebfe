"""Twin files (``docs/twin-file.md``) on disk: the one place they are read and written.

The simulator (:func:`nmsid.sim_backends.twin.load_twin`, ``write_twin``) and the analysis
(:meth:`nmsid.analysis.twin.Twin.load`, ``Twin.save``, which ``nmsid gap`` uses too) read
through :func:`read_twin_file` and write through :func:`write_twin_file`; each checks what it
needs of the content. Light on purpose (json and pathlib only): the analysis imports it
without loading the simulator.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from nmsid.sim_backends.errors import SimConfigError


class TwinReadError(SimConfigError):
    """A twin file is missing or not readable JSON (``problem`` says which)."""

    def __init__(self, path, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def write_twin_file(path, twin: dict) -> None:
    """Write ``twin`` as the file's UTF-8 JSON (indented; no NaN: the callers replace or
    refuse non-finite values first, as ``Twin.save`` does)."""
    Path(path).write_text(json.dumps(twin, indent=2, allow_nan=False) + "\n",
                          encoding="utf-8")


def read_twin_file(path) -> Any:
    """The JSON content of a twin file.

    Raises
    ------
    TwinReadError
        No such file, or not readable UTF-8 JSON.
    """
    p = Path(path)
    if not p.exists():
        raise TwinReadError(p, "no such file")
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TwinReadError(p, f"is not readable JSON ({exc})") from None
