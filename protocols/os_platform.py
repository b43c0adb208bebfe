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
from typing import Any

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


# -- the Windows API behind the switch -------------------------------------------------------
_fake_api: dict[str, Any] = {}


def windows_api(name: str) -> Any:
    """The Windows API object ``name`` that the Windows code paths call.

    Parameters
    ----------
    name : {"msvcrt", "kernel32"}
        ``msvcrt``: the C runtime module (byte-range locks); ``kernel32``:
        ``ctypes.WinDLL("kernel32", use_last_error=True)`` (console control events,
        ``SetThreadExecutionState``).

    Returns
    -------
    object
        A fake installed by :func:`fake_windows_api` (tests, the Windows emulation), else
        the real one.

    Raises
    ------
    RuntimeError
        If the real API is asked for on a machine that is not Windows (for example
        ``NMSID_PLATFORM=windows`` on Linux without the emulation).
    """
    if name in _fake_api:
        return _fake_api[name]
    if name not in ("msvcrt", "kernel32"):
        raise ValueError(f"unknown Windows API {name!r}: 'msvcrt' or 'kernel32'")
    if os.name != "nt":
        raise RuntimeError(f"the Windows API {name} exists only on Windows: nmsid follows "
                           "Windows here (NMSID_PLATFORM=windows?) without the Windows "
                           "emulation (nmsid.testing.windows_emulation)")
    if name == "msvcrt":  # pragma: no cover - Windows only
        import msvcrt  # only on Windows, behind the switch

        return msvcrt
    import ctypes  # pragma: no cover - Windows only

    return ctypes.WinDLL("kernel32", use_last_error=True)  # type: ignore[attr-defined]


@contextlib.contextmanager
def fake_windows_api(**apis: Any) -> Iterator[None]:
    """Answer :func:`windows_api` with the given fakes inside the ``with`` block.

    Examples
    --------
    >>> from nmsid.protocols import os_platform
    >>> with os_platform.fake_windows_api(msvcrt="fake"):
    ...     os_platform.windows_api("msvcrt")
    'fake'
    """
    previous = dict(_fake_api)
    _fake_api.update(apis)
    try:
        yield
    finally:
        _fake_api.clear()
        _fake_api.update(previous)
