"""Every module of nmsid imports where the POSIX-only modules do not exist (Windows), and
no POSIX-only module is imported outside the places the platform switch allows (issue 24,
1 and 6)."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Python's "Availability: Unix" modules that nmsid could be tempted to use.
POSIX_ONLY = ("fcntl", "resource", "termios", "pty", "tty", "pwd", "grp")
#: Where a POSIX-only module may be imported: inside a function, behind the switch
#: (os_platform.is_windows()), or in a fake that runs on Linux only. file -> modules.
ALLOWED = {
    "protocols/session_lock.py": {"fcntl"},
    "study/tasks.py": {"resource"},
    "testing/fake_windows_api.py": {"fcntl"},
    # the emulator's pseudo-terminal transport, chosen on POSIX by os_platform
    "testing/fakes/leptrino_emulator.py": {"tty"},
}
#: Known offenders owned by another branch (issue 24): remove each once it is fixed there.
OTHERS: dict[str, str] = {}
PACKAGES = ("nmsid", "cli", "protocols", "testing", "drivers", "sim_backends", "analysis",
            "export", "study", "rig")

_IMPORT_ALL = """
import importlib, importlib.abc, json, pkgutil, sys
BLOCKED = set(sys.argv[1].split(","))
# pyserial picks its backend by sys.platform when imported (serialposix needs termios,
# serialwin32 is used on Windows): import it before the block, as Windows would import
# its own backend, so the check sees nmsid's imports, not pyserial's platform dispatch.
try:
    import serial
except ImportError:
    pass
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (as on Windows)", name=name)
        return None
for name in list(sys.modules):
    if name.split(".")[0] in BLOCKED:
        del sys.modules[name]
sys.meta_path.insert(0, Block())
import nmsid
failed = {}
names = ["nmsid"] + [m.name for m in pkgutil.walk_packages(nmsid.__path__, "nmsid.")]
for pkg in ("nmsid.cli", "nmsid.protocols", "nmsid.testing", "nmsid.drivers",
            "nmsid.sim_backends", "nmsid.analysis", "nmsid.export", "nmsid.study", "nmsid.rig"):
    mod = importlib.import_module(pkg)
    names += [pkg] + [m.name for m in pkgutil.walk_packages(mod.__path__, pkg + ".")]
for name in sorted(n for n in set(names) if not n.endswith("__main__")):
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed[name] = f"{type(exc).__name__}: {exc}"
print(json.dumps({"n": len(set(names)), "failed": failed}))
"""


def _module_file(name: str) -> str:
    parts = name.split(".")[1:]
    return "/".join(parts) + ".py" if parts else "nmsid/__init__.py"


def test_every_module_imports_without_the_posix_only_modules():
    proc = subprocess.run([sys.executable, "-c", _IMPORT_ALL, ",".join(POSIX_ONLY)],
                          capture_output=True, text=True, cwd=str(ROOT), timeout=300,
                          check=False, env={"QT_QPA_PLATFORM": "offscreen",
                                            "PATH": "/usr/bin:/bin",
                                            "OPENBLAS_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["n"] > 100  # the walk found the project
    failed = {n: why for n, why in result["failed"].items()
              if _module_file(n) not in OTHERS}
    assert failed == {}


def _posix_imports(path: Path) -> list[tuple[str, int, bool]]:
    """(module, line, at module level) for each import of a POSIX-only module."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(n) for n in tree.body}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module]
        else:
            continue
        for name in names:
            if name.split(".")[0] in POSIX_ONLY:
                found.append((name.split(".")[0], node.lineno, id(node) in top))
    return found


def _project_files():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield path.relative_to(ROOT).as_posix(), path


@pytest.mark.parametrize("rel, path", list(_project_files()), ids=lambda v: str(v))
def test_no_posix_only_module_outside_the_switch(rel, path):
    if rel in OTHERS:
        pytest.xfail(OTHERS[rel])
    for module, line, top_level in _posix_imports(path):
        assert not top_level, f"{rel}:{line}: import {module} at module level"
        assert module in ALLOWED.get(rel, set()), (
            f"{rel}:{line}: import {module} outside the places os_platform allows "
            f"(tests/test_windows_imports.py ALLOWED)")


def test_the_static_check_sees_module_level_and_nested_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os, fcntl\nfrom pwd import getpwnam\ndef f():\n    import resource\n",
                 encoding="utf-8")
    assert _posix_imports(f) == [("fcntl", 1, True), ("pwd", 2, True), ("resource", 4, False)]
