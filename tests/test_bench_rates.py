"""bench/rates.py: Wilson intervals against their closed forms, and the verdict rule."""

from __future__ import annotations

import math

import pytest


@pytest.fixture(scope="module")
def rates(load_bench_script):
    return load_bench_script("rates")


@pytest.mark.parametrize("n", [1, 6, 20, 120, 1830])
def test_wilson_closed_forms_at_zero_and_all(rates, n):
    z2 = 1.96 ** 2
    lo, hi = rates.wilson(0, n)
    assert lo == 0.0 and hi == pytest.approx(100 * z2 / (n + z2))
    lo, hi = rates.wilson(n, n)
    assert hi == pytest.approx(100.0) and lo == pytest.approx(100 * n / (n + z2))


def test_wilson_half_is_symmetric_and_nan_without_data(rates):
    lo, hi = rates.wilson(50, 100)
    assert lo + hi == pytest.approx(100.0)
    assert all(math.isnan(x) for x in rates.wilson(0, 0))


def test_verdicts(rates):
    assert rates.verdict(120, 120, ">=", 95.0) == "met"          # lower bound 96.9 %
    assert rates.verdict(118, 120, ">=", 95.0) == "point estimate only"
    assert rates.verdict(20, 20, ">=", 90.0) == "point estimate only"  # lower 83.9 %
    assert rates.verdict(10, 12, ">=", 90.0) == "missed"
    assert rates.verdict(0, 1830, "<=", 2.0) == "met"
    assert rates.verdict(0, 100, "<=", 2.0) == "point estimate only"  # upper 3.7 %
    assert rates.verdict(3, 100, "<=", 2.0) == "missed"
    assert rates.verdict(0, 0, ">=", 90.0) == "missed"
    with pytest.raises(ValueError):
        rates.verdict(1, 2, ">", 50.0)
    assert rates.rate(118, 120, ">=", 95.0).endswith("target >= 95 %: point estimate only")
