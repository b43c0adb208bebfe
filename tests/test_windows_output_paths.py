"""Outputs on Windows (issue 24, 5): a forced output over a file open in another program
keeps the fresh results; a folder's writability is tried, not asked of os.access; the
default sessions folder is never inside the Windows folder."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from nmsid.protocols import os_platform
from nmsid.protocols.errors import OutputPathError
from nmsid.protocols.output_paths import (
    check_output,
    default_sessions_dir,
    output_dir,
    output_file,
    write_manifest,
)
from nmsid.testing.platforms import WINE_FOLDER_RENAME
from nmsid.testing.windows_emulation import emulate_windows

_HOLD = ("import sys; f = open(sys.argv[1], 'rb'); print('open', flush=True); "
         "sys.stdin.read()")


class _OpenElsewhere:
    """Another process (Excel, say) holds ``path`` open."""

    def __init__(self, path: Path):
        self.proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(path)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None and self.proc.stdout.readline() == "open\n"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.proc.communicate("")


def test_forced_output_over_a_file_open_elsewhere_keeps_the_new_results(tmp_path):
    target = tmp_path / "parameters.csv"
    target.write_text("old\n", encoding="utf-8")
    with emulate_windows(), _OpenElsewhere(target), pytest.raises(OutputPathError) as err, \
            output_file(target, force=True) as tmp:
        Path(tmp).write_bytes(b"new results\n")
    kept = tmp_path / "parameters-new.csv"
    assert kept.read_bytes() == b"new results\n"
    assert target.read_text(encoding="utf-8") == "old\n"
    message = str(err.value)
    assert f"{target}: cannot be replaced" in message and str(kept) in message
    assert "\n" not in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["parameters-new.csv",
                                                          "parameters.csv"]


@pytest.mark.wine_gap(WINE_FOLDER_RENAME)
def test_forced_folder_output_with_a_file_open_inside_keeps_both(tmp_path):
    target = tmp_path / "gap"
    target.mkdir()
    (target / "report.csv").write_text("old\n", encoding="utf-8")
    write_manifest(target)  # an earlier nmsid result
    (tmp_path / "gap-new").mkdir()  # taken: the next free name is used
    with emulate_windows(), _OpenElsewhere(target / "report.csv"), \
            pytest.raises(OutputPathError, match="gap-new-2"), \
            output_dir(target, force=True) as tmp:
        (Path(tmp) / "report.csv").write_text("new\n", encoding="utf-8")
    assert (tmp_path / "gap-new-2" / "report.csv").read_text(encoding="utf-8") == "new\n"
    assert (target / "report.csv").read_text(encoding="utf-8") == "old\n"


def test_on_windows_a_folder_is_tried_not_asked_of_os_access(tmp_path, monkeypatch):
    real_mkstemp = tempfile.mkstemp

    def refuse(*args, dir=None, **kwargs):
        if dir is not None and Path(dir) == tmp_path:
            raise PermissionError(13, "Access is denied", str(dir))
        return real_mkstemp(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    monkeypatch.setattr("os.access", lambda *a, **k: True)  # what Windows answers
    with os_platform.forced("windows"), pytest.raises(OutputPathError, match="cannot write in"):
        check_output(tmp_path / "out.csv")
    with os_platform.forced("posix"):
        assert check_output(tmp_path / "out.csv") == tmp_path / "out.csv"
    monkeypatch.undo()
    with os_platform.forced("windows"):
        assert check_output(tmp_path / "out.csv") == tmp_path / "out.csv"
    assert list(tmp_path.iterdir()) == []  # the probe left nothing


@pytest.mark.parametrize("cwd, expected", [
    ("C:\\Windows\\System32", "C:\\Users\\lab\\Documents\\nmsid\\sessions"),
    ("c:\\windows", "C:\\Users\\lab\\Documents\\nmsid\\sessions"),
    ("C:\\WindowsApps\\x", "sessions"),
    ("D:\\fes-study", "sessions"),
])
def test_default_sessions_folder_is_never_the_windows_folder(cwd, expected):
    env = {"SystemRoot": "C:\\Windows", "USERPROFILE": "C:\\Users\\lab"}
    with os_platform.forced("windows"):
        got = default_sessions_dir(cwd, env)
    assert str(got).replace("/", "\\") == expected
    with os_platform.forced("posix"):
        assert default_sessions_dir("/usr/lib", env) == Path("sessions")


def test_a_failed_rename_in_puts_the_old_folder_back_and_keeps_the_new(tmp_path, monkeypatch):
    import os

    target = tmp_path / "gap"
    target.mkdir()
    (target / "report.csv").write_text("old\n", encoding="utf-8")
    write_manifest(target)  # an earlier nmsid result
    real_rename = os.rename

    def rename(src, dst, *a, **k):
        if Path(dst) == target and ".nmsid-tmp-" in Path(src).name and "-old-" not in str(src):
            raise PermissionError(13, "Access is denied", str(src))
        return real_rename(src, dst, *a, **k)

    monkeypatch.setattr(os, "rename", rename)
    with pytest.raises(OutputPathError, match="kept in"), \
            output_dir(target, force=True) as tmp:
        (Path(tmp) / "report.csv").write_text("new\n", encoding="utf-8")
    assert (target / "report.csv").read_text(encoding="utf-8") == "old\n"
    assert (tmp_path / "gap-new" / "report.csv").read_text(encoding="utf-8") == "new\n"
