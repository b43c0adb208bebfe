"""The search: every candidate is a valid, interlock-passing configuration; the cheapest
candidate meeting the target is chosen; a miss is reported as a miss."""

import dataclasses

import numpy as np
import pytest

from nmsid.analysis.design.candidates import Candidate, paper_candidate, rest_for, search_space
from nmsid.analysis.design.predict import Predictor
from nmsid.analysis.design.prior import population_prior
from nmsid.analysis.design.search import design, parse_target
from nmsid.protocols.session_file import Calibration
from nmsid.protocols.waveforms import trial_waveform
from nmsid.rig.safety import check_waveform


def test_every_input_of_the_search_space_is_a_valid_config_under_the_ceilings():
    space = search_space()
    assert len(space) > 100
    stims = [c.stimulation_s for c in space]
    assert stims == sorted(stims)
    seen = {}
    for c in space:
        seen.setdefault((c.input_kind, c.chirp_s, c.chirp_f0_Hz, c.chirp_f1_Hz,
                         c.rE_amplitude, c.multisine_tones), c)
    cal = Calibration(3.0, 16.0, 2.5, 16.0, 0.5, 5.0)        # Imax at the 16 mA ceiling
    for c in seen.values():
        cfg = c.config()
        for sE in (min(c.sE_levels), 1.0):
            wf = trial_waveform(cfg.protocol, sE, cal)
            check_waveform(wf.I_ext_mA, wf.I_flex_mA, fs_Hz=wf.fs_Hz, carrier_Hz=1000.0,
                           ceiling_ext_mA=16.0, ceiling_flex_mA=16.0, device_max_mA=16.0)
            assert np.all(wf.rE >= 0) and np.all(wf.rE <= 1)


def test_rests_keep_the_papers_duty_cycle():
    assert rest_for(15.0) == 60.0 and rest_for(6.0) == 24.0 and rest_for(1.0) == 10.0
    assert paper_candidate().session_s == 45 * 15 + 44 * 60


@pytest.fixture(scope="module")
def predictor():
    return Predictor(population_prior(3, seed=2),
                     scatter={"Kp": 0.1, "wn_rad_s": 0.05, "zeta": 0.05})


def test_cheapest_candidate_meeting_the_target_wins_and_invalid_ones_are_skipped(predictor):
    base = Candidate(steady_s=2.0, rest_s=24.0)
    too_few = dataclasses.replace(base, chirp_s=4.0, repeats=1, label="too-few")
    invalid = dataclasses.replace(base, chirp_s=4.0, repeats=2, input_kind="multisine",
                                  multisine_tones=200, label="invalid")
    good = dataclasses.replace(base, chirp_s=4.0, repeats=3, label="good")
    dearer = dataclasses.replace(base, chirp_s=8.0, repeats=3, label="dearer")
    res = design(predictor, parse_target("paper"), [dearer, invalid, good, too_few], draws=20)
    assert res.found and res.proposal.candidate.label == "good"
    assert res.n_evaluated == 2                  # too-few, then good; invalid never counted
    assert res.proposal.ratio.max <= 1.02


def test_an_unreachable_target_is_reported_with_the_closest_candidate(predictor):
    a = Candidate(steady_s=2.0, chirp_s=4.0, repeats=1, label="a")
    b = Candidate(steady_s=2.0, chirp_s=4.0, repeats=2, label="b")
    res = design(predictor, parse_target("paper"), [a, b], draws=10)
    assert not res.found and res.proposal.candidate.label == "b"
    assert res.notes[0].startswith("no candidate met the target")
    tight = design(predictor, parse_target("Kp=0.0001"), [a, b], draws=10)
    assert not tight.found
    # an SD target still keeps the paper's selection accuracy: 3 repeats of 4 s pass
    c = Candidate(steady_s=2.0, chirp_s=4.0, repeats=3, label="c")
    d = Candidate(steady_s=2.0, chirp_s=8.0, repeats=3, label="d")
    loose = design(predictor, parse_target("Kp=0.5,wn=0.5,zeta=0.5"), [d, c], draws=10)
    assert loose.found and loose.proposal.candidate.label == "c"
