"""The physiological twin's equations (analysis.muscle.dynamics)."""

from __future__ import annotations

import numpy as np

from nmsid.analysis.muscle import literature as lit
from nmsid.analysis.muscle.dynamics import PARAM_NAMES, recruitment, simulate_batch


def _theta(**changes):
    th = lit.start_theta()
    for k, v in changes.items():
        th[PARAM_NAMES.index(k)] = v
    return th


def test_recruitment_spans_threshold_to_full():
    I = np.linspace(-0.2, 1.0, 61)
    u = recruitment(I, np.float64(0.5), np.float64(0.15))
    assert u[I <= 0].max() == 0.0
    assert abs(u[-1] - 1.0) < 1e-12
    assert np.all(np.diff(u) >= 0)


def test_constant_input_stays_in_its_steady_state():
    rE = np.full((2, 300), 0.8)
    y = simulate_batch(_theta()[None], rE, np.array([0.4, 1.0]), 0.005)[0]
    assert np.max(np.abs(y - y[:, :1])) < 1e-9
    assert y[1, 0] > y[0, 0] > 0          # more extensor drive at the higher sE


def test_deactivation_is_slower_than_activation():
    """A step up and the same step down of the extensor alone (flexor force ~0): with
    tau_deact = 4 tau_act the fall takes longer."""
    th = _theta(tau_act_s=0.01, tau_deact_s=0.04, k_s=1e-3, c_s_per_s=1e-2, F_f_N=1e-6,
                sensor_zero_s=1e-5, wn0_rad_s=200.0, zeta0=1.0)
    n = 400
    up = np.full((1, n), 0.5)
    up[0, 20:] = 1.0
    down = np.full((1, n), 1.0)
    down[0, 20:] = 0.5
    dt = 0.001
    y_up = simulate_batch(th[None], up, np.array([1.0]), dt)[0, 0]
    y_dn = simulate_batch(th[None], down, np.array([1.0]), dt)[0, 0]

    def t63(y):
        frac = (y - y[0]) / (y[-1] - y[0])
        return np.argmax(frac >= 0.632) - 20
    assert t63(y_dn) > 2 * t63(y_up)


def test_batch_rows_are_independent_parameter_sets():
    rE = 0.5 + 0.4 * np.sin(np.linspace(0, 30, 500))[None]
    th = np.vstack([_theta(), _theta(wn0_rad_s=40.0)])
    both = simulate_batch(th, rE, np.array([0.7]), 0.005)
    one = simulate_batch(th[1:], rE, np.array([0.7]), 0.005)
    assert np.allclose(both[1], one[0])
    assert not np.allclose(both[0], both[1])
