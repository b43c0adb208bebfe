"""Every docstring example in the package runs, against the installed names (nmsid.*).

The modules are found by walking the installed package, not listed by hand: a new module
with examples is tested without being registered here.
"""

from __future__ import annotations

import doctest
import importlib
import linecache
import pkgutil
from pathlib import Path

import pytest

import nmsid

# modules whose import needs an optional dependency; skipped (with the reason) without it
_NEEDS = {"nmsid.rig.gui": "PySide6", "nmsid.sim_backends.msk_": "mujoco"}


# nmsid's sub-packages are folders mapped by the install (pyproject.toml's package-dir),
# so a walk of nmsid/ alone does not see them; tests/test_packaging.py keeps this complete
SUBPACKAGES = ("protocols", "testing", "drivers", "sim_backends", "analysis", "export",
               "study", "rig", "cli")


def _walk():
    yield from pkgutil.iter_modules(nmsid.__path__, "nmsid.")
    for sub in SUBPACKAGES:
        package = importlib.import_module(f"nmsid.{sub}")
        yield from pkgutil.walk_packages(package.__path__, f"nmsid.{sub}.",
                                         onerror=lambda name: None)


def _modules_with_examples() -> list[str]:
    names = []
    for info in _walk():
        spec = importlib.util.find_spec(info.name)
        if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
            continue
        if ">>>" in Path(spec.origin).read_text(encoding="utf-8"):
            names.append(info.name)
    return sorted(names)


MODULES = _modules_with_examples()


def test_the_walk_finds_the_packages_examples():
    # the walk reaches every sub-package folder (a mapping error would find only a few)
    for name in ("nmsid.analysis.gap", "nmsid.analysis.design.api", "nmsid.analysis.qc",
                 "nmsid.sim_backends.effects", "nmsid.protocols.session_file"):
        assert name in MODULES


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    for prefix, dependency in _NEEDS.items():
        if name.startswith(prefix):
            pytest.importorskip(dependency)
    module = importlib.import_module(name)
    # doctest's runner starts a pdb per docstring, whose reset re-checks every source file
    # linecache holds (os.stat each): after a few hundred tests in one worker that is
    # thousands of stats per module, 15-145 s a module under Wine (a stat ~4 ms there).
    # The cache is only a cache: emptied, the examples run the same.
    linecache.clearcache()
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
