"""The sensor-stream stall rule survives Windows' 15.625 ms clock (issue 24, 5): a healthy
stream of 100 ms chunks (NI's 10 reads a second) read on a quantised clock never trips it;
a real stall still does, within two chunk periods and two clock steps."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from nmsid.drivers.interfaces import ForceChunk
from nmsid.rig.safety import Observation, StallRule
from nmsid.testing.windows_emulation import TIMER_TICK_S, emulate_windows

FS_HZ = 1000.0
CHUNK_S = 0.1  # NI's default of 10 reads per second


def _quantised(t_s: float) -> float:
    return math.floor(t_s / TIMER_TICK_S) * TIMER_TICK_S


def _healthy_gaps(rule: StallRule, start_s: float, jitter_s: float, n: int = 200,
                  declared_s: float | None = CHUNK_S):
    """Feed n chunks arriving every CHUNK_S (+ jitter) and check between each, as the
    engine does, on the quantised clock; return the verdicts."""
    rng = np.random.default_rng(1)
    verdicts = []
    t = start_s
    rule.start(_quantised(t), fs_Hz=FS_HZ, chunk_period_s=declared_s)
    for _ in range(n):
        # the engine checks while it waits (read timeouts of 50 ms)
        for wait in (0.05, CHUNK_S - 0.05 + rng.uniform(0, jitter_s)):
            t += wait
            verdicts.append(rule.check(Observation(_quantised(t), no_samples=True)))
        rule.feed(_quantised(t), int(CHUNK_S * FS_HZ))
    return [v for v in verdicts if v]


def test_a_healthy_100ms_stream_on_the_windows_clock_never_trips():
    with emulate_windows():
        rule = StallRule(0.1)  # the default interlock.stall_timeout_s
        assert _healthy_gaps(rule, 1000.004, jitter_s=0.02) == []
        assert rule.tick_s == TIMER_TICK_S
        assert math.isclose(rule.limit_s(), 2 * CHUNK_S + 2 * TIMER_TICK_S)
        # a driver that does not declare its chunk period: learnt from the first chunk
        assert _healthy_gaps(StallRule(0.1), 1000.004, jitter_s=0.0, declared_s=None) == []


def test_one_chunk_period_as_the_limit_would_trip_on_the_same_stream():
    """What the rule guards against: the configured 100 ms alone trips spuriously."""
    rule = StallRule(0.1)
    rule.limit_s = lambda: rule.timeout_s  # type: ignore[method-assign]
    assert _healthy_gaps(rule, 1000.004, jitter_s=0.02) != []


def test_a_real_stall_still_trips_within_two_chunks_and_two_ticks():
    with emulate_windows():
        rule = StallRule(0.1)
        rule.start(_quantised(10.0), fs_Hz=FS_HZ)
        rule.feed(_quantised(10.1), 100)
        assert rule.check(Observation(_quantised(10.1 + 0.2), no_samples=True)) is None
        verdict = rule.check(Observation(_quantised(10.1 + 0.25), no_samples=True))
    assert verdict is not None and "(limit 231 ms): stream stalled" in verdict
    assert "no force samples for 250 ms" in verdict


@pytest.mark.posix_only("needs Linux's fine clock; the emulation steps it by 15.625 ms")
def test_on_linux_a_fine_clock_keeps_the_configured_limit_without_chunks():
    rule = StallRule(0.1)
    rule.start(time.monotonic())
    assert rule.tick_s < 1e-3 and math.isclose(rule.limit_s(), 0.1, rel_tol=0.02)
    rule.feed(0.0, 500)  # no fs_Hz given: the chunk period stays unknown
    assert rule.chunk_period_s == 0.0
    assert ForceChunk(0, np.zeros(3)).n == 3
