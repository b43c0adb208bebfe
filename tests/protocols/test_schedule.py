"""Schedule: all trials present, the randomisation rules, reproducible from the seed."""

from collections import Counter
from itertools import pairwise

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols.config import Randomisation
from nmsid.protocols.errors import ScheduleError
from nmsid.protocols.schedule import (
    TrialStatus,
    make_schedule,
    schedule_from_json,
    schedule_to_json,
)

LEVELS = [round(0.30 + 0.05 * k, 2) for k in range(15)]


@given(seed=st.integers(0, 2**31), repeats=st.integers(1, 4),
       n_levels=st.integers(1, 15), mode=st.sampled_from(list(Randomisation)))
@settings(max_examples=60, deadline=None)
def test_every_level_and_repeat_exactly_once(seed, repeats, n_levels, mode):
    levels = LEVELS[:n_levels]
    s = make_schedule(levels, repeats, mode, seed)
    assert len(s) == n_levels * repeats
    assert [t.index for t in s] == list(range(len(s)))
    assert Counter((t.sE, t.repeat) for t in s) == Counter(
        (sE, r) for sE in levels for r in range(1, repeats + 1))
    assert all(t.status is TrialStatus.PENDING for t in s)
    # repeats of one level are numbered in the order they run
    for sE in levels:
        assert [t.repeat for t in s if t.sE == sE] == list(range(1, repeats + 1))
    if mode is Randomisation.BLOCKS:
        for k in range(0, len(s), repeats):
            assert len({t.sE for t in s[k:k + repeats]}) == 1


def test_same_seed_same_order_different_seed_differs():
    a = make_schedule(LEVELS, 3, Randomisation.BLOCKS, 11)
    b = make_schedule(LEVELS, 3, Randomisation.BLOCKS, 11)
    c = make_schedule(LEVELS, 3, Randomisation.BLOCKS, 12)
    assert [(t.sE, t.repeat) for t in a] == [(t.sE, t.repeat) for t in b]
    assert [t.sE for t in a] != [t.sE for t in c]


def test_blocks_order_is_actually_random():
    firsts = {make_schedule(LEVELS, 3, Randomisation.BLOCKS, s)[0].sE for s in range(40)}
    assert len(firsts) > 8


def test_full_randomisation_mixes_levels():
    s = make_schedule(LEVELS, 3, Randomisation.FULL, 4)
    runs = sum(1 for a, b in pairwise(s) if a.sE == b.sE)
    assert runs < 10  # blocks would give 30 same-level neighbours


def test_json_round_trip_and_errors():
    s = make_schedule(LEVELS[:3], 2, Randomisation.FULL, 1)
    back = schedule_from_json(schedule_to_json(s))
    assert [(t.index, t.sE, t.repeat) for t in back] == [(t.index, t.sE, t.repeat) for t in s]
    with pytest.raises(ScheduleError):
        schedule_from_json("[{]")
    with pytest.raises(ScheduleError):
        make_schedule([], 3, Randomisation.BLOCKS, 1)
    with pytest.raises(ScheduleError):
        make_schedule(LEVELS, 3, Randomisation.BLOCKS, None)
