"""Fixtures of the command-line tests: a small synthetic session file."""

from __future__ import annotations

from pathlib import Path

import pytest

from nmsid.testing.sessions import write_synthetic_session


@pytest.fixture(scope="session")
def demo_session(tmp_path_factory) -> Path:
    """A synthetic session: 3 sE levels x 2 repeats."""
    path = tmp_path_factory.mktemp("sessions") / "cli.h5"
    write_synthetic_session(path, seed=3, sE_levels=(0.3, 0.6, 1.0), repeats=2)
    return path
