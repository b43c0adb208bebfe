"""The linter (ruff) and the type checker (mypy) report nothing on the tree.

Both read their settings from pyproject.toml ([tool.ruff], [tool.mypy]). mypy cannot follow
the editable install's import hook (the package folders are mapped by
[tool.setuptools.package-dir]), so it checks a copy of the installed layout kept under
build/mypy/ (only changed files are copied; its cache makes a re-run take seconds).

Run by hand: ``python tests/test_tooling.py`` prints both reports with the repository's paths.
"""

from __future__ import annotations

import ast
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


@pytest.mark.skipif(not _installed("ruff"),
                    reason="ruff is not installed (pip install -e '.[test]')")
def test_ruff_reports_nothing():
    proc = run_ruff()
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.skipif(not _installed("mypy"),
                    reason="mypy is not installed (pip install -e '.[test]')")
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


# -- the public analysis API returns result objects, not bare dicts (issue 30, 3) ---------

#: Methods whose job IS producing a JSON-ready dict from a result object.
JSON_DICT_METHODS = {"to_dict", "as_dict"}

#: Functions whose job IS producing a JSON-ready document, with what it is.
JSON_DOCUMENTS = {
    "analysis/design/report.py: write_outputs": "design.json as written",
    "analysis/design/candidates.py: Candidate.protocol_dict":
        "a configuration's [protocol] table (config_from_dict, design.json's protocol)",
    "analysis/gap/report.py: FinalParams.for_twin":
        "the twin file's effect parameters as its JSON writes them (twin_params' input)",
    "analysis/gap/report.py: json_safe": "any value made JSON-safe (NaN -> null), as written",
    "analysis/gap/report.py: fatigue_for_twin": "the twin file's fatigue effect as written",
    "analysis/gap/verdict.py: qc_basis": "the gap report's `qc` item as written",
    "analysis/joint_twins.py: joint_twins_to_dict": "the multi-joint twin file as written",
    "analysis/joint_twins.py: load_joint_twins":
        "the file's `joints` mapping, joint name -> Twin (each a result object)",
    "analysis/report.py: parameter_titles": "axis and table titles by parameter name (labels)",
    "analysis/gap/report.py: write_outputs": "gap_report.json as written (returned to the CLI)",
    "analysis/gap/twin_out.py: twin_dict": "a twin file's JSON document (docs/twin-file.md)",
    "analysis/muscle/report.py: muscle_section":
        "gap_report.json's muscle_twin section as written",
    "analysis/muscle/report.py: twin_item":
        "the twin file's muscle_model item as written",
    "analysis/muscle/twin_form.py: muscle_entry":
        "the twin file's muscle_model item as written",
    "analysis/muscle/twin_form.py: parse_muscle_model":
        "the twin file's muscle_model item, checked and kept as read (Twin.muscle_model)",
    "analysis/twin.py: source_entry":
        "a twin file's source item as written ({file, sha256} or a label)",
}

#: Public analysis functions still returning a bare dict, each being converted by the
#: owner of its module (issue 30, 3): this list only shrinks; the integrator empties it.
KNOWN_BARE_DICTS: set[str] = set()


def _returns_dict(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> str:
    """Why ``fn`` returns a bare dict ('' if it does not): a ``dict`` / ``Dict[...]``
    return annotation (also ``dict | None``), or a ``return {...}`` / dict comprehension /
    ``dict(...)`` in its own body."""
    if fn.returns is not None:
        for part in ast.unparse(fn.returns).split("|"):
            head = part.strip().split("[")[0].rsplit(".", 1)[-1]
            if head in ("dict", "Dict"):
                return f"annotated -> {ast.unparse(fn.returns)}"
    todo: list[ast.AST] = list(fn.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue  # a nested function's returns are its own
        if isinstance(node, ast.Return) and node.value is not None:
            v = node.value
            if isinstance(v, (ast.Dict, ast.DictComp)) or (
                    isinstance(v, ast.Call) and isinstance(v.func, ast.Name)
                    and v.func.id == "dict"):
                return f"returns a dict (line {node.lineno})"
        todo.extend(ast.iter_child_nodes(node))
    return ""


def bare_dict_returns(folder: Path) -> dict[str, str]:
    """``{"<file>: <function or Class.method>": why}`` for every public function and public
    method of a public class under ``folder`` that returns a bare dict (the JSON-ready
    methods of :data:`JSON_DICT_METHODS` excepted)."""
    found = {}
    for path in sorted(folder.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if any(p.startswith("_") and p != "__init__.py" for p in path.relative_to(folder).parts):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        defs: list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]] = []
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                defs.append((node.name, node))
            elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                defs += [(f"{node.name}.{m.name}", m) for m in node.body
                         if isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef))
                         and m.name not in JSON_DICT_METHODS]
        for name, fn in defs:
            if any(part.startswith("_") for part in name.split(".")):
                continue
            why = _returns_dict(fn)
            if why:
                found[f"{rel}: {name}"] = why
    return found


def test_public_analysis_functions_return_result_objects_not_bare_dicts():
    found = bare_dict_returns(ROOT / "analysis")
    new = {k: v for k, v in found.items() if k not in KNOWN_BARE_DICTS | set(JSON_DOCUMENTS)}
    assert not new, ("public analysis functions returning a bare dict (return a frozen "
                     "dataclass with numpydoc, and a to_dict() where JSON needs one): "
                     + "; ".join(f"{k} ({v})" for k, v in sorted(new.items())))


def test_the_bare_dict_scan_sees_each_form(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text(
        "from typing import Dict\n"
        "def annotated() -> dict: ...\n"
        "def typed() -> Dict[str, float]: ...\n"
        "def optional() -> dict[str, int] | None: ...\n"
        "def literal(x):\n    return {'a': x}\n"
        "def comprehension(x):\n    return {k: 1 for k in x}\n"
        "def called(x):\n    return dict(a=x)\n"
        "def nested(x):\n    def inner():\n        return {}\n    return inner\n"
        "def _private() -> dict: ...\n"
        "class Result:\n    def to_dict(self) -> dict: ...\n"
        "    def rows(self) -> dict: ...\n", encoding="utf-8")
    found = bare_dict_returns(tmp_path / "pkg")
    assert sorted(k.split(": ")[1] for k in found) == [
        "Result.rows", "annotated", "called", "comprehension", "literal", "optional", "typed"]


def test_the_list_of_known_bare_dicts_only_shrinks():
    # an entry converted (or its function gone) is removed from KNOWN_BARE_DICTS
    stale = (KNOWN_BARE_DICTS | set(JSON_DOCUMENTS)) - set(bare_dict_returns(ROOT / "analysis"))
    assert not stale, "converted: remove from KNOWN_BARE_DICTS: " + ", ".join(sorted(stale))


# -- no override table silences a mypy error code (issue 30, 4) ------------------------

#: Modules whose [[tool.mypy.overrides]] table still disables error codes: their owners
#: are fixing them (issue 30, 4). This list only shrinks; the integrator empties it.
KNOWN_TYPE_DEBTS: set[str] = set()


def test_no_new_mypy_override_disables_an_error_code():
    mypy = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    assert "disable_error_code" not in mypy or set(mypy["disable_error_code"]) <= {
        "annotation-unchecked"}  # notes only
    silenced = set()
    for table in mypy.get("overrides", []):
        if table.get("disable_error_code"):
            modules = table["module"]
            silenced |= {modules} if isinstance(modules, str) else set(modules)
    assert silenced <= KNOWN_TYPE_DEBTS, (
        "an override table silences mypy in: " + ", ".join(sorted(silenced - KNOWN_TYPE_DEBTS))
        + "; fix the code instead")


if __name__ == "__main__":
    print(run_ruff().stdout)
    print(run_mypy()[1])
