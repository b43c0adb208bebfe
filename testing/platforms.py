"""Which Windows the tests run on: the real interpreter (on Windows or under Wine), or none.

The suite runs three ways (docs/testing.md, "Windows"): on Linux, on Linux under the
Windows emulation (:mod:`nmsid.testing.windows_emulation`), and on the Windows CPython
itself, which CI runs under Wine (``.ci/windows.sh``). A test that fails under Wine for a
gap of Wine's, not a behaviour of Windows, is marked ``@pytest.mark.wine_gap("<the gap>")``
and skipped there with that reason (the gaps met so far: ``WINE_*`` below).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any


def real_windows() -> bool:
    """True on the Windows interpreter (a Windows PC, or Wine): ``sys.platform == "win32"``."""
    return sys.platform == "win32"


@functools.cache
def wine_version() -> str | None:
    """Wine's version when this Windows interpreter runs under Wine, else None.

    Wine's ``ntdll`` exports ``wine_get_version`` (Wine's own API, absent from Microsoft's
    ntdll); failing that, a Wine prefix has the registry key ``HKCU\\Software\\Wine``.

    Examples
    --------
    >>> from nmsid.testing.platforms import wine_version
    >>> wine_version() is None or wine_version().startswith(("8", "9", "1", "unknown"))
    True
    """
    if sys.platform != "win32":  # (not real_windows(): type checkers follow this form)
        return None
    import ctypes  # noqa: PLC0415 (Windows only)

    try:
        get = ctypes.WinDLL("ntdll").wine_get_version  # type: ignore[attr-defined]
    except (OSError, AttributeError):
        get = None
    if get is not None:
        get.restype = ctypes.c_char_p
        return (get() or b"unknown").decode("ascii", "replace")
    import winreg  # noqa: PLC0415 (Windows only)

    try:
        winreg.CloseKey(winreg.OpenKey(winreg.HKEY_CURRENT_USER, r"Software\Wine"))
    except OSError:
        return None
    return "unknown"


def under_wine() -> bool:
    """True when the Windows interpreter runs under Wine, not on Windows."""
    return wine_version() is not None


#: The gaps of Wine 8.0 that tests meet (each checked under Wine; a Windows PC has none).
WINE_LOCKING = ("msvcrt.locking refuses a locked region with errno 0 (Wine's _locking sets "
                "no EACCES) and ReadFile / WriteFile ignore locked regions (Windows' locks "
                "are mandatory)")
WINE_SYMLINK = "CreateSymbolicLinkW reports success and creates nothing"
WINE_FOLDER_RENAME = ("MoveFileEx renames a folder while a file inside it is open in another "
                      "process (Windows refuses: ERROR_ACCESS_DENIED)")
WINE_DASK_CLUSTER = ("a study on distributed.LocalCluster's worker processes (started by "
                     "spawn, as WINE_PROCESS_POOL's) did not end within the 300 s test limit")
WINE_PROCESS_POOL = ("concurrent.futures.ProcessPoolExecutor never shuts down (its workers "
                     "started by spawn; multiprocessing.Pool and Process work)")


# -- pytest plugin: tests/conftest.py re-exports these names ---------------------------------
_session_emulation: Any = None
"""The run-wide :class:`~nmsid.testing.windows_emulation.WindowsEmulation`
(``--windows-emulation``), or None."""


def _windows_label() -> str | None:
    """How the run meets Windows: "Windows emulation", "Windows" (the interpreter), or None."""
    if _session_emulation is not None:
        return "Windows emulation"
    return "Windows" if real_windows() else None


def pytest_addoption(parser: Any) -> None:
    """Add ``--windows-emulation``: run the tests under the Windows emulation."""
    parser.addoption("--windows-emulation", action="store_true", default=False,
                     help="run the tests under an emulation of Windows' documented file, "
                          "descriptor, clock and module behaviours "
                          "(nmsid.testing.windows_emulation)")


def pytest_configure(config: Any) -> None:
    """Register the markers; install the emulation if asked."""
    global _session_emulation
    config.addinivalue_line("markers", "posix_only(reason): cannot apply on Windows (the "
                                       "interpreter or the emulation); skipped there with "
                                       "the reason")
    config.addinivalue_line("markers", "emulation_only(reason): tests the Linux emulation "
                                       "of Windows or drives its fakes; skipped on the "
                                       "Windows interpreter with the reason")
    config.addinivalue_line("markers", "wine_gap(reason): fails under Wine for a gap of "
                                       "Wine's, not a behaviour of Windows; skipped under "
                                       "Wine with the reason")
    if config.getoption("--windows-emulation", default=False) and _session_emulation is None:
        if real_windows():
            raise ValueError("--windows-emulation: this is the Windows interpreter; run "
                             "without it (the emulation is for Linux)")
        from nmsid.testing.windows_emulation import WindowsEmulation  # noqa: PLC0415

        _session_emulation = WindowsEmulation().install()


def pytest_unconfigure(config: Any) -> None:
    """Remove the run-wide emulation."""
    global _session_emulation
    if _session_emulation is not None:
        _session_emulation.uninstall()
        _session_emulation = None


def pytest_pycollect_makemodule(module_path: Any, parent: Any) -> Any:
    """On Windows (the interpreter, or the emulation), a test module that uses ``os.fork``,
    ``signal.SIGHUP``, ``pty``, ... is skipped as a whole, naming what it uses (it could not
    even be imported: such names are evaluated at import)."""
    label = _windows_label()
    if label is None or not Path(str(module_path)).name.startswith("test"):
        return None
    from nmsid.testing.windows_emulation import posix_only_uses  # noqa: PLC0415

    uses = posix_only_uses(module_path)
    if not uses:
        return None
    import pytest  # noqa: PLC0415

    reason = f"{label}: {Path(str(module_path)).name} uses {', '.join(uses)} (POSIX only)"

    class PosixOnlyModule(pytest.Module):
        def collect(self) -> Any:
            raise pytest.skip.Exception(reason, allow_module_level=True)

    return PosixOnlyModule.from_parent(parent, path=Path(str(module_path)))


def _reason(mark: Any, default: str) -> str:
    return mark.args[0] if mark.args else mark.kwargs.get("reason", default)


def pytest_collection_modifyitems(config: Any, items: list[Any]) -> None:
    """Skip ``posix_only`` tests on Windows (interpreter or emulation), ``emulation_only``
    tests on the Windows interpreter and ``wine_gap`` tests under Wine, each with its
    reason."""
    label = _windows_label()
    if label is None:
        return
    import pytest  # noqa: PLC0415

    for item in items:
        mark = item.get_closest_marker("posix_only")
        if mark is not None:
            item.add_marker(pytest.mark.skip(reason=f"{label}: {_reason(mark, 'POSIX only')}"))
        mark = item.get_closest_marker("emulation_only")
        if mark is not None and real_windows():
            item.add_marker(pytest.mark.skip(
                reason=f"Windows: needs the Linux emulation: {_reason(mark, 'its fakes')}"))
        mark = item.get_closest_marker("wine_gap")
        if mark is not None and under_wine():
            item.add_marker(pytest.mark.skip(
                reason=f"Wine {wine_version()}: {_reason(mark, 'a gap of Wine')}"))


try:  # the fixture needs pytest, which users of the functions above may not have
    import pytest as _pytest
except ImportError:  # pragma: no cover
    pass
else:
    @_pytest.fixture
    def windows_emulation() -> Iterator[Any]:
        """The test runs under the Windows emulation (a no-op re-install if run-wide; on
        the Windows interpreter, nothing is emulated: ``.real`` is True)."""
        if _session_emulation is not None:
            yield _session_emulation
            return
        from nmsid.testing.windows_emulation import emulate_windows  # noqa: PLC0415

        with emulate_windows() as emulation:
            yield emulation
