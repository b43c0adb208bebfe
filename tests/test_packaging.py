"""nmsid installs as one importable name, ``nmsid``, whose sub-packages are the folders."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _setuptools_table() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _folder_of(package: str, package_dir: dict[str, str]) -> Path:
    """Where setuptools finds ``package`` (the longest mapped prefix, then sub-folders)."""
    parts = package.split(".")
    for i in range(len(parts), 0, -1):
        head = ".".join(parts[:i])
        if head in package_dir:
            return ROOT / package_dir[head] / Path(*parts[i:])
    raise AssertionError(f"{package} has no entry in [tool.setuptools.package-dir]")


def test_every_package_folder_is_listed_and_mapped():
    table = _setuptools_table()
    listed, package_dir = set(table["packages"]), table["package-dir"]
    for pkg in listed:
        assert (_folder_of(pkg, package_dir) / "__init__.py").is_file(), pkg
    on_disk = set()
    for name, folder in package_dir.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            on_disk.add(".".join([name, *rel.parts]))
    assert on_disk == listed, ("pyproject.toml [tool.setuptools] packages differs from the "
                               f"folders: missing {sorted(on_disk - listed)}, "
                               f"extra {sorted(listed - on_disk)}")


def test_pip_install_adds_exactly_one_top_level_name(tmp_path):
    # a copy of the tree: pip builds in the source folder and would leave build/ behind
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".venv", ".git", "build", "*.egg-info", "__pycache__", "sessions", ".hypothesis"))
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--no-compile", "--target", str(target), str(src)],
                   check=True, capture_output=True, text=True, timeout=300)
    # bin/ holds the `nmsid` console script, not an importable name
    names = sorted(p.name for p in target.iterdir()
                   if not p.name.endswith(".dist-info") and p.name != "bin")
    assert names == ["nmsid"]
    probe = ("import importlib.util, nmsid.analysis.twin, nmsid.cli\n"
             f"print(nmsid.analysis.twin.__file__.startswith({str(target)!r}))\n"
             "print([m for m in ('analysis', 'protocols', 'rig', 'drivers', 'sim_backends',"
             " 'export', 'study', 'cli', 'testing') if importlib.util.find_spec(m)])\n")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, check=True,
                         capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"}).stdout
    assert out.split("\n")[:2] == ["True", "[]"]
