"""Reference trials (protocol option, off by default): a fixed sE spread through the
session so that fatigue is tracked (docs/identification.md)."""

from __future__ import annotations

import pytest

from nmsid.protocols.config import ConfigError, ProtocolConfig, Randomisation
from nmsid.protocols.schedule import make_schedule, schedule_from_json, schedule_to_json


def test_off_by_default_and_the_schedule_unchanged():
    p = ProtocolConfig()
    assert p.reference_sE is None and p.reference_every == 0
    plain = make_schedule(p.sE_levels, 3, Randomisation.BLOCKS, 4)
    assert len(plain) == p.n_trials == 45 and not any(t.reference for t in plain)
    assert "reference" not in schedule_to_json(plain)


@pytest.mark.parametrize("how", list(Randomisation))
def test_reference_trials_first_every_n_and_last_with_continued_repeats(how):
    levels = (0.3, 0.5, 0.7)
    s = make_schedule(levels, 3, how, 7, reference_sE=0.5, reference_every=4)
    refs = [t for t in s if t.reference]
    assert s[0].reference and s[-1].reference
    assert [t.index for t in refs] == [0, 5, 10, 12]   # 9 trials: before 1, 5, 9 and last
    assert all(t.sE == 0.5 for t in refs)
    assert sorted(t.repeat for t in s if t.sE == 0.5) == list(range(1, 8))
    regular = [(t.sE, t.repeat) for t in s if not t.reference]
    assert regular == [(t.sE, t.repeat) for t in make_schedule(levels, 3, how, 7)]
    back = schedule_from_json(schedule_to_json(s))
    assert [t.reference for t in back] == [t.reference for t in s]


def test_a_reference_sE_outside_the_levels_numbers_its_own_repeats():
    s = make_schedule((0.3, 0.7), 1, Randomisation.FULL, 1, reference_sE=0.55,
                      reference_every=1)
    assert [(t.sE, t.repeat) for t in s if t.reference] == [(0.55, 1), (0.55, 2), (0.55, 3)]


def test_config_counts_reference_trials_and_refuses_half_a_setting():
    p = ProtocolConfig(reference_sE=0.6, reference_every=9)
    assert p.n_trials == 45 + 6
    assert p.session_s == pytest.approx(51 * (p.trial_s + p.rest_s))
    with pytest.raises(ConfigError, match="reference_every"):
        ProtocolConfig(reference_sE=0.6)
    with pytest.raises(ConfigError, match="reference_every"):
        ProtocolConfig(reference_every=5)
    with pytest.raises(ConfigError):
        ProtocolConfig(reference_sE=1.5, reference_every=5)
