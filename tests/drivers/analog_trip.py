"""The force (or torque) limit on a tared analog chain, for the analog force sensor's and
the dynamometer's tests: the same ramp, the same trip, one definition."""

from __future__ import annotations

import numpy as np

from nmsid.rig.safety import ForceLimitRule, Observation


def true_load_at_trip(make_rig, slope_per_s: float, limit: float,
                      fs_Hz: float = 2000.0) -> float:
    """Start an acquisition at rest (its tare window first), then ramp the true load at
    ``slope_per_s`` from 0.2 s after the first sample; return the true load (bench time)
    at the sample where :class:`ForceLimitRule` ``limit`` trips.

    ``make_rig(load) -> (bench, lib, acq)``, ``load(t)`` the true load at bench time t.
    """
    t_ramp = [np.inf]

    def load(t):
        return np.where(t < t_ramp[0], 0.0, slope_per_s * (t - t_ramp[0]))
    bench, lib, acq = make_rig(load)
    rule = ForceLimitRule(limit)
    try:
        acq.configure(fs_Hz)
        acq.start(None, triggered=False)         # the tare window first, at rest
        tripped = None
        while lib._t_first is None:              # bench time of the block's sample 0
            c = acq.read(1.0)
            assert c is None or not rule.check(Observation(0.0, chunk=c))
        t_first = lib._t_first
        t_ramp[0] = bench.now() + 0.2            # later than any sample generated so far
        while tripped is None and bench.now() - t_first < 10.0:
            c = acq.read(1.0)
            if c is not None and len(c.force_N) and rule.check(Observation(0.0, chunk=c)):
                tripped = c.start_index + int(np.argmax(np.abs(c.force_N) > limit))
        assert tripped is not None, "the limit never tripped"
        return float(load(np.array([t_first + tripped / fs_Hz]))[0])
    finally:
        acq.close()
