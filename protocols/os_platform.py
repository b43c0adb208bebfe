"""The one switch between Windows and POSIX behaviour.

Every piece of nmsid whose behaviour depends on the operating system (the single-writer
lock, publishing the session file, console events, free-space queries, ...) asks
:func:`is_windows` at call time, never ``os.name`` or ``sys.platform`` directly, so that
the Windows code paths can run in tests on Linux against fakes that follow Microsoft's
documented semantics (docs/testing.md, "Windows").

``NMSID_PLATFORM=windows`` (or ``posix``) in the environment forces a choice; tests use
:func:`forced` instead.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

_ENV = "NMSID_PLATFORM"
_forced: str | None = None


def platform_name() -> str:
    """``"windows"`` or ``"posix"``: the behaviour nmsid follows now."""
    if _forced is not None:
        return _forced
    env = os.environ.get(_ENV, "").strip().lower()
    if env in ("windows", "posix"):
        return env
    return "windows" if os.name == "nt" else "posix"


def is_windows() -> bool:
    """True when nmsid follows Windows' documented file, lock and console semantics."""
    return platform_name() == "windows"


@contextlib.contextmanager
def forced(name: str) -> Iterator[None]:
    """Follow ``name`` (``"windows"`` or ``"posix"``) inside the ``with`` block (tests)."""
    if name not in ("windows", "posix"):
        raise ValueError(f"platform must be 'windows' or 'posix', not {name!r}")
    global _forced
    previous, _forced = _forced, name
    try:
        yield
    finally:
        _forced = previous
