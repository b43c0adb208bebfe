"""The house's layering, checked on the import graph of every project module.

Everything is one package, ``nmsid``, whose sub-packages are the repository's top-level
folders. Layers, lowest first: nmsid (the root: errors) < protocols, testing < drivers <
sim_backends < analysis (and export) < study < rig < cli. A module may import its own layer
or a lower one, always by its full ``nmsid.`` name (a bare ``import analysis`` would load a
second copy of the module, or another lab's package of that name). Imports sit at module top; a
function-local import of a project package is allowed only as a lazy load of an optional
heavy dependency behind it (PySide6, matplotlib, vendor libraries), with a comment saying
why on the import or the line above.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = {"nmsid": -1, "protocols": 0, "testing": 0, "drivers": 1, "sim_backends": 2,
          "analysis": 3, "export": 3, "study": 4, "rig": 5, "cli": 6}
NOT_PACKAGES = {"tests", "bench", "docs", "build", "dist"}
TOP_LAYER_MODULES = {"nmsid/__main__.py", "nmsid/api.py"}


def project_packages() -> list[str]:
    return sorted(p.name for p in ROOT.iterdir()
                  if (p / "__init__.py").is_file() and p.name not in NOT_PACKAGES
                  and not p.name.startswith("."))


def modules():
    for pkg in project_packages():
        for path in sorted((ROOT / pkg).rglob("*.py")):
            # ``python -m nmsid`` is the command line and ``nmsid.api`` the Python API
            # (what ``import nmsid`` exports): both sit on the top layer
            yield ("cli" if path.relative_to(ROOT).as_posix() in TOP_LAYER_MODULES
                   else pkg), path


def _module_name(path: Path) -> str:
    """The installed name: ``analysis/gap/fit.py`` is ``nmsid.analysis.gap.fit``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    if parts[0] != "nmsid":
        parts.insert(0, "nmsid")
    return ".".join(parts)


def layer_of(target: str) -> str | None:
    """The layer name of an imported module (``nmsid.rig.engine`` -> ``rig``), else None."""
    parts = target.split(".")
    if parts[0] != "nmsid":
        return None
    if len(parts) > 1 and parts[1] in LAYERS:
        return parts[1]
    return "nmsid"


def imports(path: Path):
    """(target module, line, function-local?, commented?) for every import statement."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    tree = ast.parse(source, filename=str(path))
    here = _module_name(path)
    is_pkg = path.name == "__init__.py"

    def commented(node) -> bool:
        span = lines[node.lineno - 1:node.end_lineno]
        if any("#" in text for text in span):
            return True
        above = lines[node.lineno - 2].strip() if node.lineno >= 2 else ""
        return above.startswith("#")

    def visit(node, local: bool):
        for child in ast.iter_child_nodes(node):
            inner = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                ast.Lambda, ast.ClassDef))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    yield alias.name, child.lineno, local, commented(child)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = here.split(".")
                    base = base[:len(base) - child.level + (1 if is_pkg else 0)]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module or ""
                yield target, child.lineno, local, commented(child)
            yield from visit(child, inner)

    yield from visit(tree, False)


def test_every_project_package_has_a_layer():
    unknown = [p for p in project_packages() if p not in LAYERS]
    assert not unknown, (f"new package(s) {unknown}: add them to LAYERS in {__file__} "
                         "(and docs/architecture.md)")


def test_no_module_imports_a_higher_layer():
    upward = []
    for pkg, path in modules():
        for target, line, _, _ in imports(path):
            layer = layer_of(target)
            if layer is not None and LAYERS[layer] > LAYERS[pkg]:
                upward.append(f"{path.relative_to(ROOT)}:{line} ({pkg}) imports {target}")
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_every_import_of_the_project_uses_the_nmsid_name():
    bare = []
    for _, path in modules():
        for target, line, _, _ in imports(path):
            if target.split(".")[0] in LAYERS and target.split(".")[0] != "nmsid":
                bare.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not bare, "imports without the nmsid. prefix:\n" + "\n".join(bare)


def test_function_local_imports_of_the_project_are_commented_lazy_loads():
    hidden = []
    for _, path in modules():
        for target, line, local, has_comment in imports(path):
            if local and layer_of(target) is not None and not has_comment:
                hidden.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not hidden, ("function-local imports of project packages (hoist them to the "
                        "module top, or say on the line why the load must be lazy):\n"
                        + "\n".join(hidden))


# -- the checker itself ------------------------------------------------------------------
@pytest.mark.parametrize("code,expected", [
    ("import nmsid.rig.engine\n", [("nmsid.rig.engine", False, False)]),
    ("def f():\n    from nmsid.analysis import run\n", [("nmsid.analysis", True, False)]),
    ("def f():\n    # lazy: PySide6\n    from nmsid.rig.gui import app\n",
     [("nmsid.rig.gui", True, True)]),
    ("def f():\n    import nmsid.drivers.nidaq  # vendor library\n",
     [("nmsid.drivers.nidaq", True, True)]),
    ("try:\n    from nmsid.protocols import config\nexcept ImportError:\n    pass\n",
     [("nmsid.protocols", False, False)]),
    ("class A:\n    def m(self):\n        from .b import c\n",
     [("nmsid.analysis.gap.b", True, False)]),
])
def test_the_checker_sees_local_relative_and_commented_imports(tmp_path, code, expected):
    pkg = tmp_path / "analysis" / "gap"
    pkg.mkdir(parents=True)
    mod = pkg / "mod.py"
    mod.write_text(code)
    global ROOT
    old, ROOT = ROOT, tmp_path
    try:
        got = [(t, local, c) for t, _, local, c in imports(mod)]
    finally:
        ROOT = old
    assert got == expected


def test_registering_the_commands_imports_nothing_heavy():
    """``nmsid --help`` imports only the registration modules (argparse), not numpy, h5py,
    scipy, Qt or plotting."""
    import subprocess
    import sys
    code = ("import sys, nmsid.cli; nmsid.cli.build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'h5py', 'scipy', 'PySide6', 'pyqtgraph', 'matplotlib', 'PIL')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.strip()
    assert out == "[]"
