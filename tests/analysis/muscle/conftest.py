"""Reduced sessions for the muscle-twin tests: the twin's own equations at 2 kHz (for
parameter recovery) and the independent compliant-tendon formulation of
``bench/hill_participant.py`` (for the gap diagnosis)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from nmsid.analysis.gap.data import prepare_trials
from nmsid.analysis.muscle import literature as lit
from nmsid.analysis.muscle.dynamics import PARAM_NAMES, simulate_batch
from nmsid.protocols.session_file import Trial

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench"))

FS = 1000.0
TRUE = {"F_e_N": 6.0, "F_f_N": 4.5, "c_e": 0.55, "c_f": 0.4, "w_e": 0.18, "w_f": 0.25,
        "tau_act_s": 0.02, "tau_deact_s": 0.06, "wn0_rad_s": 22.0, "zeta0": 0.4,
        "k_e": 0.6, "k_f": -0.2, "c_s_per_s": 6.0, "sensor_zero_s": 0.004, "a_max": 0.5,
        "delay_s": 0.0, "th_e": 0.08, "th_f": 0.0}


def _chirp(steady_s=3.0, chirp_s=6.0, f0=1.0, f1=8.0):
    t = np.arange(int((steady_s + chirp_s) * FS)) / FS
    tc = np.clip(t - steady_s, 0, None)
    k = f1 / f0
    ph = 2 * np.pi * f0 * chirp_s / np.log(k) * (k ** (tc / chirp_s) - 1)
    return np.where(t >= steady_s, 0.5 + 0.5 * np.sin(ph), 0.5), steady_s, chirp_s


@pytest.fixture(scope="session")
def twin_data():
    """5 levels x 2 repeats of the twin's own equations at 1 kHz, 0.02 N noise."""
    rE, steady_s, chirp_s = _chirp()
    levels = (0.3, 0.5, 0.7, 0.85, 1.0)
    plan = [(s, r) for r in (1, 2) for s in levels]
    th = np.array([TRUE[n] for n in PARAM_NAMES])
    y = simulate_batch(th[None], np.vstack([rE] * len(plan)),
                       np.array([s for s, _ in plan]), 1 / FS)[0]
    rng = np.random.default_rng(3)
    trials = [Trial(sE=s, repeat=r, fs_Hz=FS, rE=rE, I_ext_mA=rE * 0, I_flex_mA=rE * 0,
                    force_N=y[k] + 0.02 * rng.standard_normal(len(rE)), steady_s=steady_s,
                    chirp_s=chirp_s, chirp_f0_Hz=1.0, chirp_f1_Hz=8.0, name=f"t{k + 1:03d}")
              for k, (s, r) in enumerate(plan)]
    return prepare_trials(trials, path="<twin>")


@pytest.fixture(scope="session")
def hill_data():
    """The independent formulation: 5 levels x 2 repeats, a 6 s chirp."""
    from hill_participant import HillParticipant, session
    s = session(HillParticipant(), levels=(0.3, 0.5, 0.7, 0.85, 1.0), repeats=2,
                chirp_s=6.0, steady_s=3.0, seed=1)
    return prepare_trials(s.trials, path="<hill>")


__all__ = ["TRUE", "lit"]
