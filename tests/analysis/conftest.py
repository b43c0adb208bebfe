"""Shared fixtures of the analysis tests: synthetic sessions with known parameters."""

from __future__ import annotations

import pytest

from nmsid.testing import sessions


@pytest.fixture(scope="session")
def synthetic():
    """The synthetic-session generators (:mod:`nmsid.testing.sessions`)."""
    return sessions


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
