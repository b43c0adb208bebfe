"""Small synthetic sessions with known answers for the gap-diagnosis tests.

The generator here is deliberately independent of ``analysis.gap`` (scipy's zero-order-hold
discretisation at the raw 2 kHz rate, an integer-sample dead time, its own chirp), so the
tests do not check the code against itself.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from nmsid.protocols.session_file import Calibration, SessionWriter, Trial

FS = 2000.0
STEADY_S = 5.0
CHIRP_S = 10.0


def rE_chirp(fs=FS, steady_s=STEADY_S, chirp_s=CHIRP_S, f0=1.0, f1=10.0):
    n = int(round((steady_s + chirp_s) * fs))
    t = np.arange(n) / fs
    tc = np.clip(t - steady_s, 0, None)
    k = f1 / f0
    phase = 2 * np.pi * f0 * chirp_s / np.log(k) * (k ** (tc / chirp_s) - 1)
    return np.where(t >= steady_s, 0.5 + 0.5 * np.sin(phase), 0.5)


def _true_params(sE):
    Kp = 1.2 * np.exp(1.5 * sE)
    wn = 30 + 35 * sE - 15 * sE ** 2
    zeta = 0.45 + 0.35 * sE
    return Kp, wn, zeta


def write_session(path, *, levels=(0.3, 0.5, 0.7, 0.9, 1.0), repeats=3, seed=0,
                  dead_time_s=0.0, noise_N=0.04, blocks=True, fatigue_per_100s=0.0,
                  hold=True, step=None, bump=None):
    """Write a synthetic session; ``dead_time_s`` delays the force response,
    ``fatigue_per_100s`` lowers the gain linearly with cumulative stimulation.

    ``hold``: the stimulator holds each sample (zero-order hold, exact); False: a rig whose
    stimulation is the smooth signal the record samples (first-order hold: linear between
    samples). ``step = (k, t_s, height_N)``: a baseline step in the k-th trial written;
    ``bump = (ks, t_s, duration_s, height_N)``: a voluntary contraction in those trials.
    """
    rng = np.random.default_rng(seed)
    order = [(sE, r) for sE in levels for r in range(1, repeats + 1)]
    if blocks:
        perm = rng.permutation(len(levels))
        order = [(levels[i], r) for i in perm for r in range(1, repeats + 1)]
    else:
        order = [order[i] for i in rng.permutation(len(order))]
    w = SessionWriter.create(path, participant="T01", backend="test")
    w.write_calibration(Calibration(2.0, 9.0, 1.5, 8.0))
    rE = rE_chirp()
    t = np.arange(len(rE)) / FS
    cum_s = 0.0
    for k_trial, (sE, rep) in enumerate(order):
        Kp, wn, zeta = _true_params(sE)
        # exact for the stimulator's zero-order hold (each sample held for 1/FS)
        b, a, _ = signal.cont2discrete(([Kp * wn ** 2], [1, 2 * zeta * wn, wn ** 2]),
                                       1 / FS, method="zoh" if hold else "foh")
        u = rE - 0.5
        if dead_time_s > 0:
            k = int(round(dead_time_s * FS))
            u = np.concatenate([np.zeros(k), u[:-k]])
        y = signal.lfilter(np.ravel(b), np.ravel(a), u)
        if step is not None and step[0] == k_trial:
            y = y + step[2] * (t >= step[1])
        if bump is not None and k_trial in bump[0]:
            m = (t >= bump[1]) & (t < bump[1] + bump[2])
            y = y + bump[3] * m * np.sin(np.pi * (t - bump[1]) / bump[2]) ** 2
        y = y * (1.0 - fatigue_per_100s * (cum_s + t) / 100.0)
        cum_s += len(t) / FS
        noise = noise_N * rng.standard_normal(len(t)) + 0.03 * np.sin(2 * np.pi * 50 * t)
        force = y + noise + 0.3 * rng.standard_normal() + 0.01 * rng.standard_normal() * t
        I_e = 2.0 + rE * sE * 7.0
        I_f = 1.5 + (1 - rE) * sE * 6.5
        w.append_trial(Trial(sE=float(sE), repeat=rep, fs_Hz=FS, rE=rE, I_ext_mA=I_e,
                             I_flex_mA=I_f, force_N=force, steady_s=STEADY_S,
                             chirp_s=CHIRP_S))
    return path


@pytest.fixture(scope="session")
def nominal_session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("gap") / "nominal.h5", seed=1)


@pytest.fixture(scope="session")
def dead_time_session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("gap") / "dead.h5", seed=2,
                         dead_time_s=0.030)


@pytest.fixture(scope="session")
def true_params():
    """(Kp, wn, zeta) of the synthetic participant at sE."""
    return _true_params


@pytest.fixture(scope="session")
def write_synthetic():
    """The session writer, for tests that need their own variant."""
    return write_session
