"""Fixtures of the sim_backends tests."""

import pytest


@pytest.fixture
def ideal_participant():
    """The default participant with a noiseless, offset-free force chain."""
    from nmsid.sim_backends.participant import default_participant
    from nmsid.sim_backends.sensor import SensorModel
    return default_participant(sensor=SensorModel.ideal())
