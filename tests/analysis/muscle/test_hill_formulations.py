"""The independent Hill formulations of bench/hill_formulations.py: their curves against
the papers' closed forms, and a response that is finite and grows with sE."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))
import hill_formulations as hf
from hill_participant import HillParticipant


def test_curves_meet_their_defining_points():
    assert hf.fl_thelen(np.array([1.0]))[0] == pytest.approx(1.0)
    assert hf.fv_thelen(np.array([0.0]))[0] == pytest.approx(1.0)
    assert hf.fv_thelen(np.array([-1.0]))[0] == pytest.approx(0.0)
    assert hf.fv_thelen(np.array([50.0]))[0] == pytest.approx(1.4, abs=0.01)
    assert hf.fpe_thelen(np.array([1.6]))[0] == pytest.approx(1.0)      # 1 F0 at e0 = 0.6
    assert hf.fl_degroote(np.array([1.0]))[0] == pytest.approx(1.0, abs=0.02)
    v = np.linspace(-0.9, 0.5, 15)
    d1, d2, d3, d4 = hf._DG_D
    f = d1 * np.log(d2 * v + d3 + np.sqrt((d2 * v + d3) ** 2 + 1)) + d4
    np.testing.assert_allclose(hf.fv_degroote_inverse(f), v, atol=1e-9)
    assert hf.tendon_degroote(np.array([0.995]))[0] == pytest.approx(0.0)
    assert hf.fl_millard(np.array([0.44, 1.0, 1.8])) == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
    assert hf.fv_millard(np.array([-1.0, 0.0]))[0] == pytest.approx(0.0)


@pytest.mark.parametrize("form", hf.FORMULATIONS)
def test_each_formulation_answers_the_chirp_and_more_with_sE(form):
    fs = 1000.0
    t = np.arange(int(1.5 * fs)) / fs
    rE = 0.5 + 0.5 * np.sin(2 * np.pi * 2.0 * np.clip(t - 0.5, 0, None))
    force = hf.simulate(HillParticipant(noise_N=0.0), form, np.vstack([rE, rE]),
                        np.array([0.5, 1.0]), fs, np.random.default_rng(0))
    assert np.all(np.isfinite(force))
    swing = np.ptp(force[:, 700:], axis=1)
    assert 0.05 < swing[0] < swing[1] < 100.0
    with pytest.raises(ValueError, match="formulation"):
        hf.simulate(HillParticipant(), "hill1938", np.vstack([rE]), np.array([0.5]), fs,
                    np.random.default_rng(0))
