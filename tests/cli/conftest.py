"""Fixtures of the command-line tests: a small synthetic session file."""

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
def demo_session(tmp_path_factory) -> Path:
    """A synthetic session: 3 sE levels x 2 repeats."""
    path = tmp_path_factory.mktemp("sessions") / "cli.h5"
    _load_synthetic().write_synthetic_session(path, seed=3, sE_levels=(0.3, 0.6, 1.0),
                                              repeats=2)
    return path
