"""The simulated force chain's A/D: every wrench sample is a count times the LSB."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.sensor import SensorModel, SensorState

FS = 2000.0


def _force(n, amp=20.0, seed=0):
    t = np.arange(n) / FS
    return amp * np.sin(2 * np.pi * 1.3 * t) + np.random.default_rng(seed).normal(0, 1, n)


@pytest.mark.parametrize("bits,range_V,vN,vNm", [(16, 10.0, 0.02, 0.5), (12, 5.0, 0.1, 2.0),
                                                 (20, 10.0, 0.004, 0.25)])
def test_lsb_matches_closed_form(bits, range_V, vN, vNm):
    m = SensorModel(adc_bits=bits, adc_range_V=range_V, volts_per_N=vN, volts_per_Nm=vNm)
    lsb_V = 2 * range_V / 2 ** bits
    np.testing.assert_allclose(m.lsb, [lsb_V / vN] * 3 + [lsb_V / vNm] * 3, rtol=1e-15)


def test_default_chain_resolution_is_below_its_noise():
    m = SensorModel()
    assert m.lsb[0] == pytest.approx(20 / 65536 / 0.02)        # 0.0153 N per count
    assert m.lsb[0] / math.sqrt(12) < 0.25 * m.noise_N
    assert SensorModel.ideal().lsb is None


@pytest.mark.parametrize("bits,vN", [(16, 0.02), (12, 0.1), (14, 0.005)])
def test_wrench_is_on_the_count_grid_and_force_is_its_projection(bits, vN):
    m = SensorModel(adc_bits=bits, volts_per_N=vN, volts_per_Nm=vN * 25)
    f, w, over = SensorState(m, 3, FS).measure(_force(9000), 17)
    codes = w / m.lsb
    np.testing.assert_array_equal(codes, np.rint(codes))       # exactly code * lsb
    np.testing.assert_array_equal(w, np.rint(codes) * m.lsb)
    half = 2 ** (bits - 1)
    assert codes.min() >= -half and codes.max() <= half - 1
    np.testing.assert_allclose(f, w[:, :3] @ np.asarray(m.axis), rtol=0, atol=1e-12)
    assert not over


@pytest.mark.parametrize("noise_N", [0.0, 0.02, 0.06])
def test_quantisation_error_is_half_an_lsb_at_most(noise_N):
    kw = {"noise_N": noise_N, "cross_noise_N": noise_N / 2}
    fine = SensorModel(adc_bits=None, **kw)
    q = SensorModel(**kw)
    x = _force(20000, seed=4)
    f0, w0, _ = SensorState(fine, 5, FS).measure(x, 100)
    f1, w1, _ = SensorState(q, 5, FS).measure(x, 100)
    err = w1 - w0
    assert np.all(np.abs(err) <= q.lsb / 2 * (1 + 1e-9))
    # rounding of a busy signal: uniform error, RMS lsb / sqrt(12) on the force channels
    np.testing.assert_allclose(err[:, 1].std(), q.lsb[1] / math.sqrt(12), rtol=0.05)
    axis = np.asarray(q.axis)
    assert np.max(np.abs(f1 - f0)) <= np.abs(axis).sum() * q.lsb[0] / 2 * (1 + 1e-9)


def test_unquantised_chain_is_not_on_a_grid():
    m = SensorModel(adc_bits=None)
    _, w, _ = SensorState(m, 3, FS).measure(_force(5000), 0)
    lsb = SensorModel().lsb
    assert np.mean(w[:, 1] / lsb[1] == np.rint(w[:, 1] / lsb[1])) < 0.01


def test_quantised_chain_is_seeded_and_chunk_invariant():
    m = SensorModel()
    x = _force(30000, seed=9)
    f_all, w_all, _ = SensorState(m, 11, FS).measure(x, 5000)
    rng = np.random.default_rng(1)
    cuts = np.unique(np.r_[0, rng.integers(1, x.size, 25), x.size])
    s = SensorState(m, 11, FS)
    parts = [s.measure(x[a:b], 5000 + a) for a, b in pairwise(cuts)]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), f_all)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), w_all)
    f_other, _, _ = SensorState(m, 12, FS).measure(x, 5000)
    assert not np.array_equal(f_other, f_all)


def test_over_range_saturates_at_the_ad_codes():
    m = SensorModel()
    x = np.r_[np.zeros(10), np.full(10, 900.0), np.full(10, -900.0)]
    f, w, over = SensorState(m, 1, FS).measure(x, 0)
    assert over
    codes = np.rint(w[:, :3] / m.lsb[:3])
    assert codes.max() <= 2 ** 15 - 1 and codes.min() >= -2 ** 15
    assert np.abs(w[:, :3]).max() <= m.range_N
    np.testing.assert_array_equal(w / m.lsb, np.rint(w / m.lsb))


@pytest.mark.parametrize("kw", [{"adc_bits": 0}, {"adc_bits": 1.5}, {"adc_bits": True},
                                {"adc_bits": 40}, {"adc_range_V": 0.0},
                                {"volts_per_N": -1.0}, {"volts_per_Nm": math.nan}])
def test_bad_adc_settings_are_refused(kw):
    name = next(iter(kw))
    with pytest.raises(SimConfigError, match=name):
        SensorModel(**kw)
