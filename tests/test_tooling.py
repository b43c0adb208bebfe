"""The linter (ruff) and the type checker (mypy) report nothing on the tree.

Both read their settings from pyproject.toml ([tool.ruff], [tool.mypy]). mypy cannot follow
the editable install's import hook (the package folders are mapped by
[tool.setuptools.package-dir]), so it checks a copy of the installed layout kept under
build/mypy/ (only changed files are copied; its cache makes a re-run take seconds).

Run by hand: ``python tests/test_tooling.py`` prints both reports with the repository's paths.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TREE = ROOT / "build" / "mypy"


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _package_dirs() -> dict[str, str]:
    table = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return table["tool"]["setuptools"]["package-dir"]


def sync_tree() -> dict[str, Path]:
    """Copy the source tree into ``build/mypy/`` in its installed layout.

    Returns
    -------
    dict of str to Path
        Each copied folder (relative to build/mypy/, '/'-separated) -> its source folder,
        to turn mypy's paths back into the repository's.
    """
    mapping: dict[str, Path] = {}
    wanted: set[Path] = set()
    for package, folder in _package_dirs().items():
        dest_dir = TREE / Path(*package.split("."))
        src_dir = ROOT / folder
        mapping[dest_dir.relative_to(TREE).as_posix()] = src_dir
        # the top folder (nmsid/) holds only its own modules: the others are mapped
        pattern = "*.py" if package == "nmsid" else "**/*.py"
        for src in src_dir.glob(pattern):
            if "__pycache__" in src.parts:
                continue
            dest = dest_dir / src.relative_to(src_dir)
            wanted.add(dest)
            st = src.stat()
            if dest.exists():
                dt = dest.stat()
                if dt.st_size == st.st_size and dt.st_mtime_ns == st.st_mtime_ns:
                    continue
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest)
    for stale in (TREE / "nmsid").rglob("*.py"):
        if stale not in wanted:
            stale.unlink()
    return mapping


def _repo_paths(text: str, mapping: dict[str, Path]) -> str:
    """mypy's ``nmsid/analysis/x.py:3:`` -> ``analysis/x.py:3:`` (the file you edit)."""
    longest_first = sorted(mapping, key=len, reverse=True)

    def fix(match: re.Match[str]) -> str:
        path = match.group(1).replace("\\", "/")
        for prefix in longest_first:
            if path.startswith(prefix + "/"):
                src = mapping[prefix] / path[len(prefix) + 1:]
                return src.relative_to(ROOT).as_posix() + ":"
        return match.group(0)

    return re.sub(r"^(nmsid[^:\s]*\.py):", fix, text, flags=re.M)


def run_ruff() -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def run_mypy() -> tuple[int, str]:
    mapping = sync_tree()
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
         "--cache-dir", str(TREE / ".cache"), "--no-error-summary", "--hide-error-context"],
        cwd=TREE, capture_output=True, text=True, timeout=600)
    return proc.returncode, _repo_paths(proc.stdout + proc.stderr, mapping)


@pytest.mark.skipif(not _installed("ruff"), reason="ruff is not installed (pip install -e '.[test]')")
def test_ruff_reports_nothing():
    proc = run_ruff()
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.skipif(not _installed("mypy"), reason="mypy is not installed (pip install -e '.[test]')")
def test_mypy_reports_nothing():
    code, report = run_mypy()
    assert code == 0, report


def test_the_mypy_copy_maps_every_package_folder(tmp_path, monkeypatch):
    # the copy is what mypy checks: a package folder left out would pass unchecked
    monkeypatch.setattr(sys.modules[__name__], "TREE", tmp_path)
    mapping = sync_tree()
    assert set(mapping) == {p.replace(".", "/") for p in _package_dirs()}
    assert (tmp_path / "nmsid" / "analysis" / "gap" / "models.py").is_file()
    assert (tmp_path / "nmsid" / "errors.py").is_file()
    assert not (tmp_path / "nmsid" / "analysis" / "analysis").exists()
    assert _repo_paths("nmsid/analysis/gap/models.py:3: error: x", mapping) == \
        "analysis/gap/models.py:3: error: x"


def test_no_file_names_a_path_on_the_machine_it_was_written_on():
    # links go inside the repository (the session-file contract is docs/session-file.md)
    try:
        files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True,
                               text=True, check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        files = []
    if not files:
        pytest.skip("not a git checkout (or no git): the tracked files are unknown")
    found = []
    for name in files:
        path = ROOT / name
        if name == "tests/test_tooling.py" or not path.is_file():
            continue
        text = path.read_bytes().decode("utf-8", errors="replace")
        found += [f"{name}:{i}" for i, line in enumerate(text.splitlines(), 1)
                  if "/work/" in line]
    assert not found, "an absolute machine path (/work/...) in: " + ", ".join(found)


if __name__ == "__main__":
    print(run_ruff().stdout)
    print(run_mypy()[1])
