"""The rolling buffer between the engine thread and the plots (no Qt needed)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.rig.gui.live_buffer import LiveBuffer


def _chunk(start, n):
    x = np.arange(start, start + n, dtype=float)
    return x, x + 0.5, 2 * x, 3 * x


@settings(max_examples=60, deadline=None)
@given(cap=st.integers(1, 50), sizes=st.lists(st.integers(0, 80), min_size=1, max_size=20))
def test_snapshot_is_the_last_window_of_samples_in_order(cap, sizes):
    buf = LiveBuffer(window_s=cap / 10.0, fs_Hz=10.0)
    buf.start_trial(3)
    start = 0
    for n in sizes:
        buf.append(3, start, *_chunk(start, n))
        start += n
    snap = buf.snapshot()
    expected = np.arange(max(0, start - buf.capacity), start, dtype=float)
    np.testing.assert_array_equal(snap.force_N, expected)
    np.testing.assert_array_equal(snap.rE, expected + 0.5)
    np.testing.assert_array_equal(snap.I_ext_mA, 2 * expected)
    np.testing.assert_array_equal(snap.I_flex_mA, 3 * expected)
    np.testing.assert_allclose(snap.t_s, expected / 10.0)
    assert snap.trial_index == 3


def test_a_new_trial_starts_an_empty_window():
    buf = LiveBuffer(window_s=1.0, fs_Hz=100.0)
    buf.append(0, 0, *_chunk(0, 30))
    buf.start_trial(1)
    assert buf.snapshot().n == 0
    buf.append(2, 0, *_chunk(0, 5))  # a chunk of another trial also restarts the window
    snap = buf.snapshot()
    assert snap.trial_index == 2 and snap.n == 5


def test_generation_changes_only_with_data():
    buf = LiveBuffer(window_s=1.0, fs_Hz=100.0)
    g0 = buf.generation
    buf.append(0, 0, *_chunk(0, 0))
    assert buf.generation == g0
    buf.append(0, 0, *_chunk(0, 3))
    assert buf.generation == g0 + 1


def test_refuses_bad_settings_and_ragged_chunks():
    with pytest.raises(ValueError, match="window_s"):
        LiveBuffer(window_s=0)
    with pytest.raises(ValueError, match="fs_Hz"):
        LiveBuffer(fs_Hz=float("nan"))
    buf = LiveBuffer(window_s=1.0, fs_Hz=10.0)
    with pytest.raises(ValueError, match="differ in length"):
        buf.append(0, 0, np.zeros(3), np.zeros(2), np.zeros(3), np.zeros(3))


def test_concurrent_writer_and_reader_see_consistent_windows():
    buf = LiveBuffer(window_s=0.5, fs_Hz=1000.0)
    buf.start_trial(0)
    stop = threading.Event()
    bad = []

    def writer():
        start = 0
        while not stop.is_set() and start < 200_000:
            buf.append(0, start, *_chunk(start, 37))
            start += 37

    th = threading.Thread(target=writer)
    th.start()
    for _ in range(300):
        snap = buf.snapshot()
        if snap.n > 1 and not np.all(np.diff(snap.force_N) == 1.0):
            bad.append(snap.force_N)
    stop.set()
    th.join()
    assert not bad
