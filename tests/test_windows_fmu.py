"""FMU export is not hard-wired to cc and GCC (issue 24, 5): MSVC's cl or MinGW's gcc on
Windows, the binaries folder from the compiler's target, one line when there is none."""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest

from nmsid.export.errors import FmuExportError
from nmsid.export.fmu.build import (
    Compiler,
    compile_command,
    find_compiler,
    platform_of_target,
)
from nmsid.protocols import os_platform
from nmsid.testing.windows_emulation import emulate_windows


def _tool(folder: Path, name: str, script: str) -> None:
    p = folder / name
    p.write_text("#!/bin/sh\n" + script + "\n", encoding="utf-8")
    p.chmod(p.stat().st_mode | stat.S_IXUSR)


@pytest.mark.parametrize("target, folder", [
    ("x86_64-w64-mingw32", "win64"), ("i686-w64-mingw32", "win32"),
    ("x86_64-pc-windows-msvc", "win64"), ("x64", "win64"), ("x86", "win32"),
    ("ARM64", None), ("x86_64-linux-gnu", "linux64"), ("x86_64-pc-linux-gnu", "linux64"),
    ("aarch64-linux-gnu", None), ("arm64-apple-darwin23.1.0", "darwin64"),
    ("x86_64-apple-darwin", "darwin64"), ("", None)])
def test_the_binaries_folder_comes_from_the_compilers_target(target, folder):
    assert platform_of_target(target) == folder


def test_no_compiler_on_windows_is_one_line_saying_what_to_install(monkeypatch):
    monkeypatch.delenv("CC", raising=False)
    with emulate_windows(), pytest.raises(FmuExportError) as err:
        find_compiler()
    message = str(err.value)
    assert "\n" not in message and "tried cl, gcc, clang" in message
    assert "Visual Studio Build Tools" in message and "--sources-only" in message


@pytest.mark.posix_only("stands in for Windows itself with stand-in compilers on PATH, which the "
                        "emulation's empty PATH would hide")
def test_msvc_cl_is_found_on_windows_and_gets_cl_flags(tmp_path, monkeypatch):
    _tool(tmp_path, "cl", 'echo "Microsoft (R) C/C++ Optimizing Compiler Version '
                          '19.38.33130 for x64" >&2')
    _tool(tmp_path, "gcc", "echo x86_64-w64-mingw32")
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    with os_platform.forced("windows"):
        c = find_compiler()
    assert c == Compiler("msvc", str(tmp_path / "cl"), "win64")
    cmd = compile_command(c, Path("src"), Path("out/x.dll"))
    assert cmd[1:4] == ["/nologo", "/LD", "/O2"] and cmd[-1] == f"/Fe:{Path('out/x.dll')}"
    assert not any(a.startswith("-") for a in cmd[1:])


@pytest.mark.posix_only("stands in for Windows itself with stand-in compilers on PATH, which the "
                        "emulation's empty PATH would hide")
def test_mingw_gcc_is_used_without_cl_and_builds_for_win64(tmp_path, monkeypatch):
    _tool(tmp_path, "gcc", "echo x86_64-w64-mingw32")
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    with os_platform.forced("windows"):
        c = find_compiler()
    assert (c.kind, c.platform) == ("gcc", "win64")
    cmd = compile_command(c, Path("src"), Path("x.dll"))
    assert "-shared" in cmd and "-fPIC" not in cmd  # every Windows DLL is PIC
    with os_platform.forced("posix"):  # POSIX looks for cc first: not here, gcc next
        assert find_compiler().path == str(tmp_path / "gcc")


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler")
def test_on_linux_cc_builds_for_its_own_target(monkeypatch):
    monkeypatch.delenv("CC", raising=False)
    with os_platform.forced("posix"):
        c = find_compiler()
    assert c.kind == "gcc" and Path(c.path).name == "cc"
    assert c.platform == {"x86_64": "linux64"}.get(os.uname().machine, c.platform)
    assert "-fPIC" in compile_command(c, Path("s"), Path("x.so"))
