"""Small synthetic sessions with known answers for the gap-diagnosis tests.

The generator (:func:`nmsid.testing.sessions.write_gap_session`) is deliberately independent of
``analysis.gap`` (scipy's zero-order-hold discretisation at the raw 2 kHz rate, an
integer-sample dead time, its own chirp), so the tests do not check the code against
itself.
"""

from __future__ import annotations

import pytest

from nmsid.testing.sessions import gap_true_params, write_gap_session

#: The generator moved to :mod:`nmsid.testing.sessions`; the tests keep their short name.
write_session = write_gap_session
_true_params = gap_true_params


@pytest.fixture(scope="session")
def nominal_session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("gap") / "nominal.h5", seed=1)


@pytest.fixture(scope="session")
def dead_time_session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("gap") / "dead.h5", seed=2,
                         dead_time_s=0.030)


@pytest.fixture(scope="session")
def true_params():
    """(Kp, wn, zeta) of the synthetic participant at sE."""
    return _true_params


@pytest.fixture(scope="session")
def write_synthetic():
    """The session writer, for tests that need their own variant."""
    return write_session
