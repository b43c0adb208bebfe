"""The Windows-behaviour emulation does what its docstring says, and undoes it."""

from __future__ import annotations

import importlib
import locale
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from nmsid.protocols import os_platform
from nmsid.testing.platforms import windows_emulation  # noqa: F401  (the fixture)
from nmsid.testing.windows_emulation import (
    ERROR_ACCESS_DENIED,
    ERROR_SHARING_VIOLATION,
    emulate_windows,
    posix_only_uses,
)

# these check that the emulation is installed and then removed again; a run-wide
# emulation (--windows-emulation) is never removed during the run
pytestmark = pytest.mark.posix_only("checks the emulation's own install and uninstall")


def test_delete_of_a_file_open_in_this_process_is_a_sharing_violation(tmp_path):
    f = tmp_path / "live.h5"
    f.write_bytes(b"x")
    with emulate_windows(), open(f, "rb"):
        for delete in (os.remove, os.unlink):
            with pytest.raises(PermissionError) as err:
                delete(f)
            assert err.value.winerror == ERROR_SHARING_VIOLATION
        with pytest.raises(PermissionError):
            f.unlink()
    assert f.exists()
    with emulate_windows():
        os.remove(f)  # closed: allowed
    assert not f.exists()


def test_replace_onto_a_file_open_in_another_process_is_access_denied(tmp_path):
    (tmp_path / "s").mkdir()
    live, new = tmp_path / "s" / "live.h5", tmp_path / "live.h5.tmp"
    live.write_bytes(b"old")
    new.write_bytes(b"new")
    reader = subprocess.Popen([sys.executable, "-c",
                               ("import sys; f = open(sys.argv[1], 'rb'); print('ok', flush=True);"
                                " sys.stdin.read()"), str(live)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert reader.stdout.readline().strip() == "ok"
        with emulate_windows():
            with pytest.raises(PermissionError) as err:
                os.replace(new, live)
            assert err.value.winerror == ERROR_ACCESS_DENIED
            with pytest.raises(PermissionError) as err:
                os.replace(live, tmp_path / "elsewhere")  # the source held open
            assert err.value.winerror == ERROR_SHARING_VIOLATION
            with pytest.raises(PermissionError):
                shutil.rmtree(tmp_path / "s")
    finally:
        reader.communicate("")
    assert live.read_bytes() == b"old" and new.exists()
    with emulate_windows():
        os.replace(new, live)
    assert live.read_bytes() == b"new"


def test_rename_onto_an_existing_file_is_refused_and_a_folder_with_an_open_file_stays(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("a", encoding="utf-8")
    b.write_text("b", encoding="utf-8")
    folder = tmp_path / "journal"
    folder.mkdir()
    (folder / "partial.f64").write_bytes(b"")
    with emulate_windows():
        with pytest.raises(FileExistsError):
            os.rename(a, b)
        with open(folder / "partial.f64", "rb"):
            with pytest.raises(PermissionError) as err:
                os.rename(folder, tmp_path / "journal.old")
            assert err.value.winerror == ERROR_ACCESS_DENIED
            with pytest.raises(PermissionError):
                shutil.rmtree(folder)
        shutil.rmtree(folder)
    assert not folder.exists()


def test_descriptors_without_o_binary_are_text_mode(tmp_path):
    text_f, bin_f = tmp_path / "t.bin", tmp_path / "b.bin"
    with emulate_windows():
        fd = os.open(text_f, os.O_WRONLY | os.O_CREAT)
        assert os.write(fd, b"\x89HDF\r\n\x1a\n") == 8
        os.close(fd)
        fd = os.open(bin_f, os.O_WRONLY | os.O_CREAT | os.O_BINARY)
        os.write(fd, b"\x89HDF\r\n\x1a\n")
        os.close(fd)
        fd = os.open(text_f, os.O_WRONLY | os.O_APPEND)
        with os.fdopen(fd, "wb") as f:
            f.write(b"\n")
        with pytest.raises(PermissionError):
            os.open(tmp_path, os.O_RDONLY)  # a directory cannot be opened
    assert text_f.read_bytes() == b"\x89HDF\r\r\n\x1a\r\n\r\n"
    assert bin_f.read_bytes() == b"\x89HDF\r\n\x1a\n"
    assert not hasattr(os, "O_BINARY")


def test_posix_only_functions_and_modules_are_absent_then_restored():
    import fcntl  # imported before: must still be refused inside

    before = os_platform.platform_name()
    with emulate_windows():
        for name in ("statvfs", "pread", "pwrite", "fork", "openpty"):
            assert not hasattr(os, name), name
        assert not hasattr(signal, "SIGHUP")
        for module in ("fcntl", "resource", "termios", "pty", "pwd", "grp"):
            with pytest.raises(ImportError):
                importlib.import_module(module)
        assert os_platform.is_windows()
        assert shutil.which("cc") is None and shutil.which("gcc") is None
        assert shutil.which("python3") is not None or shutil.which("sh") is not None
    assert hasattr(os, "statvfs") and hasattr(signal, "SIGHUP")
    assert importlib.import_module("fcntl") is fcntl
    assert os_platform.platform_name() == before


def test_default_text_encoding_is_cp1252_with_crlf(tmp_path):
    f = tmp_path / "notes.txt"
    with emulate_windows():
        assert locale.getpreferredencoding() == "cp1252"
        f.write_text("µA\n")
        with open(f) as g:
            assert g.read() == "µA\n"
    assert f.read_bytes() == "µA\r\n".encode("cp1252")


def test_monotonic_steps_by_the_windows_timer_tick():
    with emulate_windows():
        readings = {time.monotonic() for _ in range(2000)}
        assert time.get_clock_info("monotonic").resolution == 0.015625
    assert all(abs(r / 0.015625 - round(r / 0.015625)) < 1e-9 for r in readings)
    assert time.get_clock_info("monotonic").resolution < 0.015625


def test_the_fixture_installs_the_emulation(windows_emulation):  # noqa: F811
    assert windows_emulation.installed and os_platform.is_windows()
    assert not hasattr(os, "pwrite")


def test_test_modules_that_need_posix_are_found_by_their_syntax(tmp_path):
    f = tmp_path / "test_x.py"
    f.write_text("import os, signal\nfrom tests.rig.forked_cli import fork_nmsid\n"
                 "S = [signal.SIGHUP]\ndef t():\n    import pty\n    os.fork()\n"
                 "X = 'os.statvfs in a string'\n", encoding="utf-8")
    assert posix_only_uses(f) == ["forked_cli (os.fork)", "os.fork", "pty", "signal.SIGHUP"]
    f.write_text("import os\nos.replace('a', 'b')\n", encoding="utf-8")
    assert posix_only_uses(f) == []
