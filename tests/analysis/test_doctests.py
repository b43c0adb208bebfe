"""The examples in the docstrings of the analysis modules touched by the speed work run."""

import doctest
import importlib

import pytest

MODULES = ["figures", "signal_kernels", "twin", "preprocess", "residual_tests"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(f"analysis.{name}")
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0
