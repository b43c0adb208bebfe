"""Optional signals on an exact A/D grid are stored as integer counts + scale/offset and
read back as float64 bit for bit; everything else is stored as before."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols.session_file import (
    Calibration,
    SessionWriter,
    Trial,
    counts_to_values,
    read_session,
    validate_session,
)


def _bits(a):
    return np.asarray(a, dtype=np.float64).view(np.int64)


def _trial(n, wrench, sync, rng):
    return Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=rng.uniform(0, 1, n),
                 I_ext_mA=rng.uniform(0, 12, n), I_flex_mA=rng.uniform(0, 12, n),
                 force_N=rng.normal(0, 1, n), wrench=wrench, sync=sync)


def _write(path, trials, *, gzip_level=4, store_counts=True):
    w = SessionWriter.create(path, participant="P1", gzip_level=gzip_level,
                             store_counts=store_counts)
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0))
    for t in trials:
        w.append_trial(t)


def _grid_wrench(rng, n, steps, span):
    codes = rng.integers(-span, span + 1, (n, 6))
    return codes * np.asarray(steps)


@pytest.mark.parametrize("level", [None, 1, 4])
@pytest.mark.parametrize("steps,span,dtype", [
    ([20 / 65536 / 0.02] * 3 + [20 / 65536 / 0.5] * 3, 32768 - 1, np.int16),  # 16-bit chain
    ([1e-7, 3e-7, 1 / 3, 2.5, 7.0, 1e3], 100, np.int8),          # odd steps, few codes
    ([20 / 2 ** 24 / 0.013] * 6, 2 ** 23, np.int32),             # a 24-bit A/D
])
def test_grid_wrench_round_trips_as_counts(tmp_path, level, steps, span, dtype):
    import h5py
    rng = np.random.default_rng(span)
    n = 4001
    w = _grid_wrench(rng, n, steps, span)
    sync = rng.integers(0, 2, n) * 5.0
    path = tmp_path / "s.h5"
    _write(path, [_trial(n, w, sync, rng)], gzip_level=level)
    with h5py.File(path, "r") as f:
        d = f["trials/t001/wrench"]
        assert d.dtype == dtype and d.shape == (n, 6)
        assert d.attrs["scale"].shape == (6,)
        assert f["trials/t001/sync"].dtype == np.int8
        assert f["trials/t001/force_N"].dtype == np.float64   # required: float64 always
    assert validate_session(path) == []
    back = read_session(path).trials[0]
    assert back.wrench.dtype == np.float64 and back.sync.dtype == np.float64
    np.testing.assert_array_equal(_bits(back.wrench), _bits(w))
    np.testing.assert_array_equal(_bits(back.sync), _bits(sync))


@settings(max_examples=60, deadline=None)
@given(log_step=st.floats(-9, 4), bits=st.integers(2, 31), n=st.integers(1, 300),
       seed=st.integers(0, 2 ** 31), identifiable=st.booleans())
def test_any_grid_through_zero_is_detected_and_exact(tmp_path_factory, log_step, bits, n,
                                                     seed, identifiable):
    """Always bit-exact; stored as counts whenever two samples lie within 4096 steps (the
    documented limit of the detector: with sparser codes any few floats lie on some grid)."""
    rng = np.random.default_rng(seed)
    step = 10.0 ** log_step * rng.uniform(1, 10)
    half = 2 ** (bits - 1)
    codes = rng.integers(-half, half, n)
    if identifiable or n == 1:
        codes[0] = rng.integers(1, min(half, 4096) + 1)
    sync = codes * step
    path = tmp_path_factory.mktemp("g") / "s.h5"
    _write(path, [_trial(n, None, sync, rng)])
    back = read_session(path).trials[0]
    np.testing.assert_array_equal(_bits(back.sync), _bits(sync))
    import h5py
    with h5py.File(path, "r") as f:
        stored = f["trials/t001/sync"].dtype
    if identifiable or n == 1:
        assert np.issubdtype(stored, np.integer)


@pytest.mark.parametrize("case", ["noise", "decimal_rounding", "negative_zero", "nan",
                                  "one_column_off", "too_many_codes"])
def test_values_off_a_grid_stay_floats_and_exact(tmp_path, case):
    import h5py
    rng = np.random.default_rng(5)
    n = 3000
    w = _grid_wrench(rng, n, [0.01525878906] * 6, 30000)
    if case == "noise":
        w = rng.normal(0, 3, (n, 6))
    elif case == "decimal_rounding":
        w = np.round(rng.uniform(-5, 5, (n, 6)), 2)   # k / 100 is not k * 0.01 bit for bit
    elif case == "negative_zero":
        w[5, 2] = -0.0
    elif case == "nan":
        w[7, 1] = np.nan
    elif case == "one_column_off":
        w[:, 4] = rng.normal(0, 1, n)
    elif case == "too_many_codes":
        w[:, 0] = rng.integers(-2 ** 40, 2 ** 40, n) * 1e-3
    path = tmp_path / "s.h5"
    _write(path, [_trial(n, w, None, rng)])
    with h5py.File(path, "r") as f:
        assert np.issubdtype(f["trials/t001/wrench"].dtype, np.floating)
    back = read_session(path).trials[0]
    np.testing.assert_array_equal(_bits(back.wrench), _bits(w))


def test_store_counts_off_keeps_floats(tmp_path):
    import h5py
    rng = np.random.default_rng(6)
    w = _grid_wrench(rng, 500, [0.25] * 6, 1000)
    _write(tmp_path / "s.h5", [_trial(500, w, None, rng)], store_counts=False)
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f["trials/t001/wrench"].dtype == np.float32      # exact in float32
    np.testing.assert_array_equal(read_session(tmp_path / "s.h5").trials[0].wrench, w)


def test_reader_applies_offset_written_by_another_writer(tmp_path):
    """Counts with a non-zero offset (e.g. a unipolar A/D: 0 ... 65535 -> -10 ... 10 V)."""
    import h5py
    rng = np.random.default_rng(7)
    n = 1000
    path = tmp_path / "s.h5"
    _write(path, [_trial(n, None, None, rng)])
    codes = rng.integers(0, 65536, (n, 6)).astype(np.uint16)
    scale = np.array([20 / 65536] * 3 + [0.001] * 3)
    offset = np.array([-10.0] * 3 + [-32.768] * 3)
    sync_codes = rng.integers(0, 4096, n).astype(np.int16)
    with h5py.File(path, "a") as f:
        d = f["trials/t001"].create_dataset("wrench", data=codes)
        d.attrs["scale"], d.attrs["offset"] = scale, offset
        s = f["trials/t001"].create_dataset("sync", data=sync_codes)
        s.attrs["scale"], s.attrs["offset"] = 10 / 4096, 0.5
    assert validate_session(path) == []
    back = read_session(path).trials[0]
    want = offset[None, :] + scale[None, :] * codes.astype(np.float64)
    np.testing.assert_array_equal(_bits(back.wrench), _bits(want))
    np.testing.assert_array_equal(back.sync, 0.5 + (10 / 4096) * sync_codes)
    assert back.wrench[:, :3].min() >= -10.0 and back.wrench[:, :3].max() < 10.0


def test_counts_without_scale_are_reported(tmp_path):
    import h5py
    rng = np.random.default_rng(8)
    path = tmp_path / "s.h5"
    _write(path, [_trial(100, None, None, rng)])
    with h5py.File(path, "a") as f:
        f["trials/t001"].create_dataset("wrench", data=np.zeros((100, 6), dtype=np.int16))
    problems = validate_session(path)
    assert len(problems) == 1 and "wrench" in problems[0] and "scale" in problems[0]


def test_counts_to_values_closed_form():
    counts = np.array([[-3, 0, 7], [1, 2, -32768]], dtype=np.int16)
    got = counts_to_values(counts, [0.5, 2.0, 1e-3], [1.0, 0.0, -2.0])
    np.testing.assert_array_equal(got, [[-0.5, 0.0, -1.993], [1.5, 4.0, -2.0 - 32.768]])
