"""The shared part of the pulse stimulators (``drivers/pulse_stimulator.py``), on both
drivers against their byte-level fakes: a closed-loop stream that runs dry waits for its
next updates and then paces them at the pulse rate again."""

from __future__ import annotations

import time

import numpy as np
import pytest

from nmsid.drivers.rehastim2 import Rehastim2Stimulator
from nmsid.drivers.sciencemode4 import P24, Sm4Stimulator
from nmsid.testing.fakes.fake_rehastim2 import FakeRehastim2
from nmsid.testing.fakes.fake_sciencemode4 import FakeSm4

RATE_HZ = 40.0


def _rehastim2():
    dev = FakeRehastim2()
    stim = Rehastim2Stimulator("FAKE", ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                               extensor_channel=1, flexor_channel=2, pulse_rate_Hz=RATE_HZ,
                               open_port=dev.open)
    # the times the device took an update with current (SM2 1.3: the pulses that follow)
    return stim, lambda: [t for t, v in dev.updates if v and v.get(1, (0, 0))[1] > 0]


def _p24():
    dev = FakeSm4("P24")
    stim = Sm4Stimulator("FAKE", P24, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                         extensor_channel=1, flexor_channel=2, pulse_rate_Hz=RATE_HZ,
                         open_port=dev.open, clock=dev.clock)
    return stim, lambda: [p[0] for p in dev.pulses if p[1] == 1]


@pytest.mark.parametrize("make", [_rehastim2, _p24], ids=["rehastim2", "p24"])
def test_a_stream_that_ran_dry_waits_then_paces_its_updates_again(make):
    # A tracking stream's writer stalls for 12 pulse periods. The stream must neither end
    # (the RehaStim2's did, its queue empty) nor, afterwards, send the late updates back to
    # back as fast as the device answers (the P24's did: its time base stayed behind):
    # its time base moves by the wait, so the updates after it go out one period apart.
    stim, pulse_times = make()
    stim.connect()
    try:
        stim.open_stream(20.0, 20.0, RATE_HZ)
        stim.write_stream(np.full(4, 4.0), np.zeros(4))
        stim.start()
        time.sleep(12 / RATE_HZ + 4 / RATE_HZ)
        n_before = len(pulse_times())
        stim.write_stream(np.full(10, 6.0), np.zeros(10))
        deadline = time.monotonic() + 10.0      # generous: a loaded host (not timed)
        while len(pulse_times()) < n_before + 10 and time.monotonic() < deadline:
            time.sleep(0.02)
        stim.close_stream()
        after = np.asarray(pulse_times()[n_before:])
    finally:
        stim.disconnect()
    assert n_before >= 3 and len(after) >= 8, (n_before, len(after))
    gaps = np.diff(after)
    # the median: a late wake-up may shorten one gap; a burst shortens all of them (~3 ms)
    assert np.median(gaps) >= 0.8 / RATE_HZ, gaps
