"""Public library APIs only (issue 38, item 1): no module of nmsid or its benchmarks imports
a private scipy module or loads a compiled extension by file path, and the filters the
analysis and the simulator run are ``scipy.signal``'s own functions."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the product's packages: neither private scipy modules nor modules loaded by file path
PACKAGES = ("analysis", "cli", "drivers", "export", "nmsid", "protocols", "rig",
            "sim_backends", "study", "testing")
#: the benchmarks: no private scipy module (bench/run.py loads bench scripts by path)
BENCH = "bench"
#: importlib machinery that loads a module from a file chosen by the caller
LOADERS = {"ExtensionFileLoader", "SourceFileLoader", "SourcelessFileLoader",
           "spec_from_file_location", "spec_from_loader", "module_from_spec"}


def _private(module: str) -> bool:
    parts = module.split(".")
    return parts[0] == "scipy" and any(p.startswith("_") for p in parts[1:])


def problems_in(source: str, name: str, loaders: bool = True) -> list[str]:
    """Private scipy imports, private scipy attributes and (with ``loaders``) file loaders
    in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source, filename=name)):
        if isinstance(node, ast.Import):
            found += [f"{name}:{node.lineno} imports {a.name}" for a in node.names
                      if _private(a.name)]
        elif isinstance(node, ast.ImportFrom) and node.module:
            if _private(node.module):
                found.append(f"{name}:{node.lineno} imports from {node.module}")
            elif node.module.split(".")[0] == "scipy":
                found += [f"{name}:{node.lineno} imports {node.module}.{a.name}"
                          for a in node.names if a.name.startswith("_")]
            if loaders and node.module.startswith("importlib"):
                found += [f"{name}:{node.lineno} imports {a.name}" for a in node.names
                          if a.name in LOADERS]
        elif isinstance(node, ast.Attribute):
            if loaders and node.attr in LOADERS:
                found.append(f"{name}:{node.lineno} uses {node.attr}")
            chain, cur = [node.attr], node.value
            while isinstance(cur, ast.Attribute):
                chain.append(cur.attr)
                cur = cur.value
            if isinstance(cur, ast.Name) and cur.id in ("scipy", "sp") and any(
                    c.startswith("_") and not c.startswith("__") for c in chain):
                found.append(f"{name}:{node.lineno} reads scipy.{'.'.join(chain[::-1])}")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if "scipy/signal/_" in node.value or "scipy.signal._" in node.value:
                found.append(f"{name}:{node.lineno} names a private scipy module")
    return found


def _sources(*packages):
    for pkg in packages:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield path.relative_to(ROOT).as_posix(), path.read_text(encoding="utf-8")


def test_no_module_imports_a_private_scipy_module_or_loads_one_by_path():
    sources = list(_sources(*PACKAGES))
    assert len(sources) > 100                    # the walk did find the product
    found = [p for name, source in sources for p in problems_in(source, name)]
    assert found == []


def test_no_benchmark_imports_a_private_scipy_module():
    found = [p for name, source in _sources(BENCH)
             for p in problems_in(source, name, loaders=False)]
    assert found == []


@pytest.mark.parametrize("code", [
    "from scipy.signal._sosfilt import _sosfilt",
    "import scipy.signal._sigtools",
    "from scipy.signal import _sigtools",
    "import scipy\nf = scipy.signal._sigtools._linear_filter",
    "import importlib.machinery\nimportlib.machinery.ExtensionFileLoader('a', 'b')",
    "from importlib.util import spec_from_file_location",
    "p = 'scipy/signal/_sosfilt'",
])
def test_the_check_finds_each_way_of_reaching_a_private_module(code):
    assert problems_in(code, "x.py") != []


def test_the_check_passes_public_imports():
    code = ("import scipy.signal\nfrom scipy.signal import lfilter, sosfiltfilt\n"
            "from scipy import linalg\nx = scipy.signal.__name__\n")
    assert problems_in(code, "x.py") == []


def test_the_filters_the_product_runs_are_scipys_public_functions():
    import scipy.ndimage
    import scipy.signal

    from nmsid.analysis import input_timing, preprocess, second_order, twin
    from nmsid.analysis.gap import fit, models
    from nmsid.analysis.qc import checks

    assert preprocess.sosfiltfilt is scipy.signal.sosfiltfilt
    assert preprocess.butter is scipy.signal.butter
    assert preprocess.convolve1d is scipy.ndimage.convolve1d
    assert checks.sosfiltfilt is scipy.signal.sosfiltfilt
    for module in (second_order, twin, input_timing, fit):
        assert module.lfilter is scipy.signal.lfilter, module.__name__
    assert models.signal is scipy.signal
