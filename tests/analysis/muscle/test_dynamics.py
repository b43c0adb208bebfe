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
    th = _theta(tau_act_s=0.01, tau_deact_s=0.04, k_e=1e-3, k_f=1e-3, c_s_per_s=1e-2, F_f_N=1e-6,
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


def _plain_rk4(th, rE, sE, dt):
    """The twin's equations stepped one by one (the form before the affine map): frozen
    activation time constant per step, classical Runge-Kutta with the activation linear
    over the step."""
    p = dict(zip(PARAM_NAMES, th, strict=True))
    Fm = 0.5 * (p["F_e_N"] + p["F_f_N"])
    u_e = recruitment(rE * sE, p["c_e"], p["w_e"], p["th_e"])
    u_f = recruitment((1 - rE) * sE, p["c_f"], p["w_f"], p["th_f"])
    a = np.array([u_e[0], u_f[0]])

    def coef(a):
        D = p["F_e_N"] * a[0] - p["F_f_N"] * a[1]
        K = p["wn0_rad_s"] ** 2 * (1 + (p["k_e"] * p["F_e_N"] * a[0]
                                        + p["k_f"] * p["F_f_N"] * a[1]) / Fm)
        C = 2 * p["zeta0"] * p["wn0_rad_s"] + p["c_s_per_s"] * (
            p["F_e_N"] * a[0] + p["F_f_N"] * a[1]) / Fm
        return p["wn0_rad_s"] ** 2 * D, K, C
    d, K, _ = coef(a)
    x, v = d / K, 0.0
    out = []
    for k in range(len(rE)):
        out.append(x + p["sensor_zero_s"] * v)
        u = np.array([u_e[k], u_f[k]])
        g = 0.5 + 1.5 * p["a_max"] * a
        tau = np.where(u > a, p["tau_act_s"] * g, p["tau_deact_s"] / g)
        a1 = u + (a - u) * np.exp(-dt / tau)
        (d0, K0, C0), (dm, Km, Cm), (d1, K1, C1) = coef(a), coef(0.5 * (a + a1)), coef(a1)
        k1 = (v, d0 - K0 * x - C0 * v)
        k2 = (v + 0.5 * dt * k1[1], dm - Km * (x + 0.5 * dt * k1[0]) - Cm * (v + 0.5 * dt * k1[1]))
        k3 = (v + 0.5 * dt * k2[1], dm - Km * (x + 0.5 * dt * k2[0]) - Cm * (v + 0.5 * dt * k2[1]))
        k4 = (v + dt * k3[1], d1 - K1 * (x + dt * k3[0]) - C1 * (v + dt * k3[1]))
        x = x + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        a = a1
    return np.array(out)


def test_batched_simulation_equals_the_step_by_step_equations():
    """The vectorised form (activation first, the mechanics' Runge-Kutta steps as affine
    maps) is the same arithmetic as stepping the equations one by one."""
    th = _theta(k_e=0.3, k_f=-0.2, th_e=0.1, th_f=-0.05, a_max=0.6, c_s_per_s=8.0)
    rE = 0.5 + 0.45 * np.sin(np.cumsum(np.linspace(0.02, 0.6, 700)))
    y = simulate_batch(th[None], rE[None], np.array([0.9]), 0.01)[0, 0]
    ref = _plain_rk4(th, rE, 0.9, 0.01)
    assert np.max(np.abs(y - ref)) < 1e-10 * np.max(np.abs(ref))
    assert np.ptp(ref) > 0.1


def test_linear_limit_matches_the_closed_form_step_response():
    """Fast activation, no active stiffness or damping, no sensor zero: a step of the
    extensor's drive gives the mount's second-order step response
    1 - exp(-zeta wn t) (cos(wd t) + zeta wn / wd sin(wd t)); the activation is taken as
    linear over the step it jumps in, so the step acts from that step's middle."""
    wn, z = 20.0, 0.3
    th = _theta(tau_act_s=1e-6, tau_deact_s=1e-6, k_e=0.0, k_f=0.0, c_s_per_s=0.0,
                sensor_zero_s=0.0, wn0_rad_s=wn, zeta0=z, F_f_N=1e-9)
    dt = 0.001
    rE = np.full(1500, 0.5)
    rE[1:] = 1.0
    y = simulate_batch(th[None], rE[None], np.array([1.0]), dt)[0, 0]
    t = np.maximum((np.arange(1500) - 1.5) * dt, 0.0)
    wd = wn * np.sqrt(1 - z ** 2)
    step = 1 - np.exp(-z * wn * t) * (np.cos(wd * t) + z * wn / wd * np.sin(wd * t))
    y0, y1 = y[0], y[-1]
    ss = (y - y0) / (y1 - y0)
    assert np.max(np.abs(ss[2:] - step[2:])) < 2e-4


def test_a_recruitment_threshold_recruits_nothing_below_it():
    I = np.linspace(0.0, 1.0, 101)
    u = recruitment(I, np.float64(0.5), np.float64(0.2), 0.25)
    assert u[I <= 0.25].max() == 0.0 and u[I > 0.26].min() > 0.0
    assert abs(u[-1] - 1.0) < 1e-12
