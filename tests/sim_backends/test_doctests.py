"""The examples in the sim_backends docstrings run."""

import doctest
import importlib

import pytest

MODULES = ["curves", "effects", "faults", "clocks", "rig", "twin", "population",
           "msk_population"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(f"sim_backends.{name}")
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0
