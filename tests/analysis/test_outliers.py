"""Quartiles as MATLAB's prctile and the IQR rule, against hand-computed values."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.analysis.outliers import iqr_fences, iqr_inliers, matlab_prctile


def test_prctile_hand_values():
    # n = 4: positions 12.5, 37.5, 62.5, 87.5 percent
    x = [4.0, 1.0, 3.0, 2.0]
    assert matlab_prctile(x, 25) == pytest.approx(1.5)     # 1 + (25-12.5)/25
    assert matlab_prctile(x, 50) == pytest.approx(2.5)
    assert matlab_prctile(x, 75) == pytest.approx(3.5)
    assert matlab_prctile(x, 10) == 1.0                    # below the first position
    assert matlab_prctile(x, 95) == 4.0                    # above the last
    # n = 5: positions 10, 30, 50, 70, 90
    y = [1, 2, 3, 4, 100]
    assert matlab_prctile(y, 25) == pytest.approx(1.75)    # 1 + 15/20
    assert matlab_prctile(y, 75) == pytest.approx(28.0)    # 4 + 5/20 * 96


def test_prctile_ignores_nan_and_handles_empty():
    assert matlab_prctile([np.nan, 1.0, 2.0, 3.0], 50) == 2.0
    assert np.isnan(matlab_prctile([np.nan], 50))
    with pytest.raises(ValueError, match="percentile"):
        matlab_prctile([1, 2], 101)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=40),
       st.floats(0, 100))
def test_prctile_equals_numpy_hazen(values, p):
    assert matlab_prctile(values, p) == pytest.approx(
        np.percentile(values, p, method="hazen"), rel=1e-9, abs=1e-9)


def test_iqr_rule_hand_case():
    x = [1.0, 2.0, 3.0, 4.0, 100.0]
    f = iqr_fences(x)
    assert (f.q1, f.q3) == pytest.approx((1.75, 28.0))
    assert f.high == pytest.approx(28.0 + 1.5 * 26.25)
    assert iqr_inliers(x).tolist() == [True, True, True, True, False]
    # values exactly on a fence are kept (the rule is "outside the fences")
    v = [0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.0]   # Q1 = Q3 = 1: fences at 1
    assert iqr_inliers(v).tolist() == [False] + [True] * 6 + [False]


def test_iqr_fifteen_levels_like_the_paper():
    # wn over 15 levels with one wild value: quartiles by hand (positions 100(i-0.5)/15)
    wn = np.array([20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 90.0])
    # Q1: position of 25 % lies between i=4 (23.33 %) and i=5 (30 %): 23 + 0.25 * 1
    assert matlab_prctile(wn, 25) == pytest.approx(23.25)
    assert matlab_prctile(wn, 75) == pytest.approx(30.75)
    keep = iqr_inliers(wn)
    assert keep.sum() == 14 and not keep[-1]
    assert iqr_inliers(wn, k=100).all()
