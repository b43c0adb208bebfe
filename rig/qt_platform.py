"""Before Qt starts: are the system libraries of Qt's X11 (xcb) platform plugin there?

PySide6 wheels bring Qt but not the X11 client libraries its ``xcb`` platform plugin links
against. On a fresh Linux desktop one of them is often missing (libxcb-cursor0,
libxcb-icccm4, libxcb-keysyms1 on Debian/Ubuntu) and Qt then aborts the process with
``could not load the Qt platform plugin "xcb"`` and a page of hints. :func:`check_xcb`
asks the dynamic loader for the same libraries first and raises one
:class:`QtPlatformLibrariesMissing` naming the packages to install; ``nmsid gui`` prints it
in one line and exits 2.

The list is the plugin's own: the ``NEEDED`` entries of ``libqxcb.so`` and
``libQt6XcbQpa.so.6`` in PySide6 6.x (``objdump -p``), minus the C/C++ runtime and Qt's own
libraries, with the Debian/Ubuntu package that ships each (``dpkg -S``).
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Callable

from nmsid.errors import MissingDependency

#: soname -> Debian/Ubuntu package, for every system library Qt 6's xcb plugin links.
XCB_PLUGIN_LIBRARIES: dict[str, str] = {
    "libxcb.so.1": "libxcb1",
    "libX11.so.6": "libx11-6",
    "libX11-xcb.so.1": "libx11-xcb1",
    "libxcb-cursor.so.0": "libxcb-cursor0",
    "libxcb-icccm.so.4": "libxcb-icccm4",
    "libxcb-image.so.0": "libxcb-image0",
    "libxcb-keysyms.so.1": "libxcb-keysyms1",
    "libxcb-randr.so.0": "libxcb-randr0",
    "libxcb-render.so.0": "libxcb-render0",
    "libxcb-render-util.so.0": "libxcb-render-util0",
    "libxcb-shape.so.0": "libxcb-shape0",
    "libxcb-shm.so.0": "libxcb-shm0",
    "libxcb-sync.so.1": "libxcb-sync1",
    "libxcb-util.so.1": "libxcb-util1",
    "libxcb-xfixes.so.0": "libxcb-xfixes0",
    "libxcb-xkb.so.1": "libxcb-xkb1",
    "libxkbcommon.so.0": "libxkbcommon0",
    "libxkbcommon-x11.so.0": "libxkbcommon-x11-0",
    "libGL.so.1": "libgl1",
    "libglib-2.0.so.0": "libglib2.0-0",
    "libgthread-2.0.so.0": "libglib2.0-0",
}


class QtPlatformLibrariesMissing(MissingDependency):
    """System libraries of Qt's xcb platform plugin are missing (the message says which
    packages to install)."""

    def __init__(self, missing: dict[str, str]):
        self.missing = dict(missing)
        packages = " ".join(sorted(set(missing.values())))
        super().__init__(
            f"Qt's X11 platform plugin (xcb) cannot load: missing system "
            f"librar{'y' if len(missing) == 1 else 'ies'} {', '.join(sorted(missing))}; "
            f"install them (Debian/Ubuntu: sudo apt-get install {packages}) or choose another "
            "Qt platform, e.g. QT_QPA_PLATFORM=wayland or offscreen")


def _loads(soname: str) -> bool:
    """Whether the dynamic loader finds and loads ``soname`` (as Qt's loader would)."""
    try:
        ctypes.CDLL(soname)
    except OSError:
        return False
    return True


def xcb_will_be_used(environ=None, platform: str | None = None) -> bool:
    """Whether Qt will start with its xcb plugin.

    True on Linux when ``QT_QPA_PLATFORM`` names xcb first, or is unset outside a Wayland
    session (Qt 6 picks wayland by itself when ``XDG_SESSION_TYPE=wayland`` and
    ``WAYLAND_DISPLAY`` is set).
    """
    env = os.environ if environ is None else environ
    if not (platform or sys.platform).startswith("linux"):
        return False
    chosen = env.get("QT_QPA_PLATFORM", "").strip()
    if chosen:
        first = chosen.split(";")[0].split(":")[0].strip()
        return first == "xcb"
    return not (env.get("XDG_SESSION_TYPE") == "wayland" and env.get("WAYLAND_DISPLAY"))


def check_xcb(environ=None, platform: str | None = None,
              loads: Callable[[str], bool] | None = None) -> None:
    """Raise :class:`QtPlatformLibrariesMissing` if Qt will use xcb and cannot load it.

    Parameters
    ----------
    environ : mapping, optional
        Environment to read ``QT_QPA_PLATFORM`` etc. from (default ``os.environ``).
    platform : str, optional
        ``sys.platform`` stand-in (tests).
    loads : callable, optional
        ``soname -> bool``, whether the library loads (default: ask the dynamic loader).

    Raises
    ------
    QtPlatformLibrariesMissing
        Naming the missing libraries and the Debian/Ubuntu packages that ship them.
    """
    if not xcb_will_be_used(environ, platform):
        return
    loads = loads or _loads
    missing = {so: pkg for so, pkg in XCB_PLUGIN_LIBRARIES.items() if not loads(so)}
    if missing:
        raise QtPlatformLibrariesMissing(missing)
