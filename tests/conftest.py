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

#: Tests skipped on the Windows interpreter from here, not by a mark in their module (being
#: rewritten elsewhere): node id prefix -> reason.
WINDOWS_SKIPS = {
    "tests/analysis/test_signal_kernels.py::test_sosfiltfilt_is_scipys_bit_for_bit":
        "compares with scipy's sosfiltfilt bit for bit; scipy's Windows build differs in "
        "the last bits (another compiler's rounding); being rewritten on public scipy",
    "tests/analysis/test_signal_kernels.py::test_threaded_sosfiltfilt_is_scipys_bit_for_bit":
        "compares with scipy's sosfiltfilt bit for bit; scipy's Windows build differs in "
        "the last bits (another compiler's rounding); being rewritten on public scipy",
    "tests/protocols/test_lti_kernels.py::test_the_simulators_filter_equals_scipys_across"
    "_chunks_and_coefficient_changes[kernel-0.02]":
        "compares with scipy's lfilter to 1e-9 while scipy's Windows build differs by "
        "1.1e-9 at tau 0.02 s (another compiler's rounding); being rewritten with a "
        "tolerance stated from the algorithm",
    "tests/protocols/test_lti_kernels.py::test_the_simulators_filter_equals_scipys_across"
    "_chunks_and_coefficient_changes[numpy-0.02]":
        "compares with scipy's lfilter to 1e-9 while scipy's Windows build differs by "
        "1.1e-9 at tau 0.02 s (another compiler's rounding); being rewritten with a "
        "tolerance stated from the algorithm",
}


def pytest_collection_modifyitems(config, items):
    platforms.pytest_collection_modifyitems(config, items)
    if not platforms.real_windows():
        return
    for item in items:
        for prefix, reason in WINDOWS_SKIPS.items():
            if item.nodeid.replace("\\", "/").startswith(prefix):
                item.add_marker(pytest.mark.skip(reason=f"Windows: {reason}"))


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


@pytest.fixture(params=["kernel", "numpy"])
def filter_path(request, monkeypatch):
    """Run a filter test on each of the product's two filter paths: scipy's compiled kernels
    (``nmsid.protocols.lti_kernels``: ``lfilter``'s and ``sosfilt``'s) and the numpy
    fallback, forced by hiding both kernels."""
    from nmsid.protocols import lti_kernels
    if request.param == "numpy":
        monkeypatch.setattr(lti_kernels, "_kernel", None)
        monkeypatch.setattr(lti_kernels, "source", "unavailable")
        monkeypatch.setattr(lti_kernels, "_sos_kernel", None)
        monkeypatch.setattr(lti_kernels, "sos_source", "unavailable")
    assert lti_kernels.kernel_available() == (request.param == "kernel")
    assert lti_kernels.sos_kernel_available() == (request.param == "kernel")
    return request.param
