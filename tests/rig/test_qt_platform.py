"""nmsid gui checks the xcb plugin's system libraries before Qt does: one line, exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from nmsid.cli import main
from nmsid.errors import MissingDependency
from nmsid.rig import qt_platform
from nmsid.rig.qt_platform import (
    XCB_PLUGIN_LIBRARIES,
    QtPlatformLibrariesMissing,
    check_xcb,
    xcb_will_be_used,
)

ROOT = Path(__file__).resolve().parents[2]


def loader_without(*absent):
    return lambda soname: soname not in absent


@pytest.mark.parametrize("env,platform,expected", [
    ({}, "linux", True),
    ({"QT_QPA_PLATFORM": "xcb"}, "linux", True),
    ({"QT_QPA_PLATFORM": "xcb:nograb"}, "linux", True),
    ({"QT_QPA_PLATFORM": "xcb;wayland"}, "linux", True),
    ({"QT_QPA_PLATFORM": "offscreen"}, "linux", False),
    ({"QT_QPA_PLATFORM": "wayland;xcb"}, "linux", False),
    ({"XDG_SESSION_TYPE": "wayland", "WAYLAND_DISPLAY": "wayland-0"}, "linux", False),
    ({"XDG_SESSION_TYPE": "wayland"}, "linux", True),          # no compositor to talk to
    ({}, "darwin", False),
    ({"QT_QPA_PLATFORM": "xcb"}, "win32", False),
])
def test_when_qt_will_use_xcb(env, platform, expected):
    assert xcb_will_be_used(env, platform) is expected


def test_all_libraries_present_passes():
    check_xcb({"QT_QPA_PLATFORM": "xcb"}, "linux", loads=lambda so: True)


@pytest.mark.parametrize("absent", [
    ("libxcb-cursor.so.0",),
    ("libxcb-icccm.so.4", "libxcb-keysyms.so.1"),
    ("libglib-2.0.so.0", "libgthread-2.0.so.0"),           # one package, two libraries
    tuple(XCB_PLUGIN_LIBRARIES),
])
def test_missing_libraries_are_named_with_their_packages(absent):
    with pytest.raises(QtPlatformLibrariesMissing) as info:
        check_xcb({}, "linux", loads=loader_without(*absent))
    msg = str(info.value)
    assert "\n" not in msg and isinstance(info.value, MissingDependency)
    assert set(info.value.missing) == set(absent)
    packages = msg.split("apt-get install ")[1].split(")")[0].split()
    assert packages == sorted({XCB_PLUGIN_LIBRARIES[so] for so in absent})
    for so in absent:
        assert so in msg
    present = set(XCB_PLUGIN_LIBRARIES) - set(absent)
    assert not any(f" {so}" in msg or f"{so}," in msg for so in present)


def test_other_platforms_are_not_checked():
    def boom(soname):
        raise AssertionError("must not probe libraries")
    check_xcb({"QT_QPA_PLATFORM": "offscreen"}, "linux", loads=boom)
    check_xcb({}, "darwin", loads=boom)


def test_nmsid_gui_prints_one_line_and_exits_2(monkeypatch, capsys):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setenv("QT_QPA_PLATFORM", "xcb")
    monkeypatch.setattr(qt_platform, "_loads", loader_without("libxcb-icccm.so.4"))
    assert main(["gui", "--backend", "sim"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "libxcb-icccm.so.4" in err and "apt-get install libxcb-icccm4)" in err


@pytest.mark.skipif(sys.platform == "win32", reason="Windows: the loader is asked for "
                    "Linux's shared libraries (xcb's); there is no libc.so.6 to find")
def test_the_real_loader_finds_what_is_installed():
    assert qt_platform._loads("libc.so.6") is True
    assert qt_platform._loads("libnmsid-surely-absent.so.9") is False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="xcb is Linux only")
def test_real_process_without_the_libraries_on_this_machine():
    absent = [so for so in XCB_PLUGIN_LIBRARIES if not qt_platform._loads(so)]
    if not absent:
        pytest.skip("this machine has every xcb plugin library; nothing to refuse")
    env = dict(os.environ, QT_QPA_PLATFORM="xcb", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "nmsid.cli", "gui", "--backend", "sim"],
                          env=env, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "could not load the Qt platform plugin" not in proc.stderr
    for so in absent:
        assert so in lines[0] and XCB_PLUGIN_LIBRARIES[so] in lines[0]
