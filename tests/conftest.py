"""Fixtures shared by every test area."""

from __future__ import annotations

from pathlib import Path

import pytest

# Windows (nmsid.testing.platforms): --windows-emulation runs the tests under the Linux
# emulation of Windows; @pytest.mark.posix_only("why") skips a test there and on the Windows
# interpreter, @pytest.mark.emulation_only("why") on the Windows interpreter only; the
# windows_emulation fixture installs the emulation for one test (a no-op on Windows)
from nmsid.testing import platforms
from nmsid.testing.platforms import (  # noqa: F401
    pytest_addoption,
    pytest_configure,
    pytest_pycollect_makemodule,
    pytest_unconfigure,
    windows_emulation,
)


def pytest_collection_modifyitems(config, items):
    platforms.pytest_collection_modifyitems(config, items)


@pytest.fixture(autouse=True, scope="session")
def lsl_on_this_machine_only(tmp_path_factory):
    """Lab Streaming Layer stays on this machine in every test (issue 43): ``LSLAPICFG``
    names an ``lsl_api.cfg`` with ``ResolveScope = machine`` and IPv6 off, set before any
    test imports pylsl; no test sends LSL's default multicast or broadcast."""
    import os
    if "LSLAPICFG" not in os.environ:
        from nmsid.rig.lsl import machine_only_config
        machine_only_config(tmp_path_factory.mktemp("lsl"))
    yield


@pytest.fixture
def session_reads(monkeypatch):
    """Count how often each HDF5 file is opened for reading (``h5py.File`` in mode "r").

    Returns a function ``reads(path) -> int``. Counted at h5py, below the session-file
    reader, so the count stays right however that reader is organised.
    """
    import h5py

    counts: dict[Path, int] = {}
    original = h5py.File

    class CountingFile(original):
        def __init__(self, name, mode="r", *args, **kwargs):
            if mode == "r" and isinstance(name, (str, Path)):
                key = Path(name).resolve()
                counts[key] = counts.get(key, 0) + 1
            super().__init__(name, mode, *args, **kwargs)

    monkeypatch.setattr(h5py, "File", CountingFile)
    return lambda path: counts.get(Path(path).resolve(), 0)


@pytest.fixture(scope="session")
def load_bench_script():
    """Import a script of ``bench/`` by its file (bench/ is not a package) under a
    test-only module name: ``load_bench_script("rates")``."""
    import importlib.util
    import sys

    def load(stem: str):
        name = f"bench_{stem}_under_test"
        if name in sys.modules:
            return sys.modules[name]
        spec = importlib.util.spec_from_file_location(
            name, Path(__file__).resolve().parents[1] / "bench" / f"{stem}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        return module
    return load
