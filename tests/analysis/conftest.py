"""Shared fixtures of the analysis tests: synthetic sessions with known parameters."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


def _load_synthetic():
    name = "nmsid_bench_synthetic_sessions"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCH / "synthetic_sessions.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def synthetic():
    """The ``bench/synthetic_sessions.py`` module."""
    return _load_synthetic()


SMALL_LEVELS = (0.3, 0.45, 0.6, 0.75, 0.9, 1.0)


@pytest.fixture(scope="session")
def small_session(tmp_path_factory, synthetic):
    """(path, truth): 6 sE levels x 2 repeats, full-length trials at 2000 Hz."""
    path = tmp_path_factory.mktemp("sessions") / "small.h5"
    truth = synthetic.write_synthetic_session(path, seed=7, sE_levels=SMALL_LEVELS, repeats=2)
    return path, truth


@pytest.fixture(scope="session")
def second_session(tmp_path_factory, synthetic):
    """A second participant for group runs (same small design, other parameters)."""
    path = tmp_path_factory.mktemp("sessions") / "second.h5"
    truth = synthetic.write_synthetic_session(path, seed=8, participant="P02",
                                              sE_levels=SMALL_LEVELS, repeats=2)
    return path, truth
