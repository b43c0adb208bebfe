"""dev.py, the entry point that replaces make (issue 24, 4): venv layout per system, the
re-install stamp, the test command's arguments."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("nmsid_dev", ROOT / "dev.py")
dev = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dev)


def test_the_venv_interpreter_is_where_each_system_puts_it(tmp_path):
    assert dev.venv_python(tmp_path, windows=True) == tmp_path / "Scripts" / "python.exe"
    assert dev.venv_python(tmp_path, windows=False) == tmp_path / "bin" / "python"


def test_the_stamp_changes_with_pyproject(tmp_path):
    p = tmp_path / "pyproject.toml"
    p.write_text("[project]\nname = 'a'\n", encoding="utf-8")
    first = dev.stamp_path(tmp_path, p)
    assert dev.stamp_path(tmp_path, p) == first
    p.write_text("[project]\nname = 'b'\n", encoding="utf-8")
    assert dev.stamp_path(tmp_path, p) != first


def test_an_installed_venv_is_not_reinstalled(tmp_path, monkeypatch):
    (tmp_path / "bin").mkdir()
    (tmp_path / "Scripts").mkdir()
    for py in (dev.venv_python(tmp_path, True), dev.venv_python(tmp_path, False)):
        py.touch()
    dev.stamp_path(tmp_path).touch()
    monkeypatch.setattr(dev, "_run", lambda *a, **k: (_ for _ in ()).throw(AssertionError))
    assert dev.ensure_venv(tmp_path) == dev.venv_python(tmp_path)


def test_the_test_command_passes_pytest_arguments_and_the_emulation():
    assert dev.pytest_args([]) == ["-m", "pytest", "-q", "-n", "2"]
    assert dev.pytest_args(["tests/test_layers.py", "-x"], windows_emulation=True) == [
        "-m", "pytest", "-q", "-n", "2", "--windows-emulation", "tests/test_layers.py", "-x"]
    assert "2" not in dev.pytest_args(["-n", "0"])[:5]
    assert "-n" not in dev.pytest_args(["-p", "no:xdist"])[:5]


def test_an_unknown_command_is_one_line_of_usage():
    proc = subprocess.run([sys.executable, str(ROOT / "dev.py"), "deploy"], check=False,
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "invalid choice: 'deploy'" in proc.stderr


def test_the_build_requires_a_setuptools_that_reads_an_spdx_license():
    """``license = "BSD-3-Clause"`` (PEP 639) is read from setuptools 77 on; an older one
    (75.6 on the Windows interpreter without build isolation) rejects the project."""
    import re
    import tomllib

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert isinstance(pyproject["project"]["license"], str)
    [req] = [r for r in pyproject["build-system"]["requires"] if r.startswith("setuptools")]
    floor = re.fullmatch(r"setuptools>=(\d+)(\.\d+)*", req)
    assert floor is not None and int(floor.group(1)) >= 77
