"""The physiological twin's equations, simulated for many trials and parameter sets at once.

Two Hill-type muscles (extensor ``e``, flexor ``f``) on the isometric elbow, each driven by
its normalised stimulation intensity (paper eqs. 1-4): ``I_e = rE sE``, ``I_f = (1 - rE) sE``.

1. **Recruitment** (Crago, Peckham & Thrope 1980; Durfee & MacLean 1989): the fraction of
   the muscle's fibres an electrode recruits, a sigmoid of intensity normalised to 0 at
   ``I = 0`` (the calibrated threshold) and 1 at ``I = 1``:
   ``u(I) = (S(x) - S(0)) / (S(1) - S(0))``, ``S(x) = 1 / (1 + exp(-(x - c) / w))``,
   ``x = max(I - th, 0) / (1 - th)``: ``th`` is the muscle's own threshold on the
   calibrated scale (the calibration's threshold is an estimate: a muscle may start
   below or above it; recruitment curves rise from a threshold, Durfee & MacLean 1989).
2. **Activation dynamics** (Thelen 2003, after Winters 1995; the form Millard et al. 2013
   and MuJoCo use): ``a' = (u - a) / tau``, ``tau = tau_act (0.5 + 1.5 a)`` while
   activating (``u > a``), ``tau_deact / (0.5 + 1.5 a)`` while deactivating: separate
   activation and deactivation time constants. ``a`` here is the recruited share of the
   muscle normalised to 1 at ``I = 1``; the time constants see the muscle's own activation
   ``a_max a`` (surface electrodes reach only part of a muscle: ``a_max`` < 1).
3. **Force** at the sensor: ``F_m a_m`` (``F_m`` = maximal isometric force of muscle ``m``
   at the fixture angle, through its moment arm: the force-length factor at that length is
   a constant and is part of ``F_m``).
4. **Limb, fixture and muscle mechanics** in force units (``x`` = the force the fixture
   spring carries, what the sensor reads):
   ``x'' = wn0^2 (F_e a_e - F_f a_f - (1 + k_e phi_e + k_f phi_f) x)
   - (2 zeta0 wn0 + c_s (phi_e + phi_f)) x'``
   with ``phi_m = F_m a_m / ((F_e + F_f) / 2)`` (each muscle's active force, relative).
   ``wn0``, ``zeta0``: the passive limb on its compliant mount (forearm inertia against
   strap, tissue and sensor stiffness; the series-elastic tendon is in series with that
   compliance and lumps into it - with the joint held, tendon and mount stretch together
   and the protocol cannot tell them apart). ``k_e``, ``k_f``: the stiffness each active
   muscle adds, per unit activation relative to the mount's (the force-length slope and
   short-range stiffness; Hogan 1984; Cui et al. 2008); signed: a muscle held on the
   descending limb of its force-length curve (longer than optimal) loses force as the
   joint yields towards its lengthening, a negative stiffness. ``c_s``: the damping active muscle
   adds per unit activation (the Hill force-velocity slope at zero velocity: a shortening fibre
   pulls less, a lengthening one more, ``dF/dv = -F (1 + 1/A) / v_max`` with Hill's
   ``A`` about 0.25; Hill 1938; Zajac 1989). Both make the response's ``wn`` and ``zeta``
   depend on sE, as the paper measures.
5. **Sensor**: it reads the mount's spring force plus the part of the mount's damping
   force that passes through it (strap viscosity in series with the cell):
   ``y = x + tau_z x'`` (``sensor_zero_s`` = ``tau_z``, a zero of the measurement chain).
6. **Delay**: ``delay_s``, the electromechanical delay and any misalignment of the
   recorded force and the commanded rE beyond the session's timing estimate; the model is
   stationary, so it is a time shift of its output, applied by the caller
   (:mod:`nmsid.analysis.muscle.fit` in the frequency domain,
   :func:`nmsid.analysis.muscle.twin_form.simulate_muscle` by interpolation).

The simulation starts in the steady state of ``rE = 0.5`` (the trial's lead-in) and steps
the activation exactly over each step for the step's frozen time constant and the
mechanics by classical Runge-Kutta (4th order), with the input held per step (the
commanded rE is piecewise constant). Given the activation, the mechanics are linear, so
each step's Runge-Kutta map is an affine map formed for all steps at once; only the
activation and that affine recurrence run step by step. Everything is vectorised over a leading
batch axis, so one call simulates the finite-difference perturbations of every parameter together.
"""

from __future__ import annotations

import numpy as np

#: Parameter names, in the order of the parameter vector (physical units).
PARAM_NAMES = ("F_e_N", "F_f_N", "c_e", "c_f", "w_e", "w_f", "tau_act_s", "tau_deact_s",
               "wn0_rad_s", "zeta0", "k_e", "k_f", "c_s_per_s", "sensor_zero_s",
               "a_max", "delay_s", "th_e", "th_f")


def recruitment(I: np.ndarray, c: np.ndarray, w: np.ndarray, th: np.ndarray | float = 0.0
                ) -> np.ndarray:
    """Recruited fraction ``u(I)`` (see module), 0 at ``I <= 0``, 1 at ``I = 1``.

    Parameters
    ----------
    I : ndarray
        Normalised intensity, any shape broadcasting against ``c``, ``w``.
    c, w : ndarray
        Sigmoid midpoint and width (normalised intensity).
    th : ndarray or float
        The muscle's own recruitment threshold on the calibrated scale (0: the
        calibration's threshold is the muscle's); the sigmoid acts on
        ``(I - th) / (1 - th)``, nothing is recruited below ``th``.
    """
    def S(x):
        return 1.0 / (1.0 + np.exp(-(x - c) / w))
    s0, s1 = S(0.0), S(1.0)
    x = (np.maximum(I, 0.0) - th) / (1.0 - th)
    return np.clip((S(np.maximum(x, 0.0)) - s0) / (s1 - s0), 0.0, None)


def _activation(U: np.ndarray, ta: np.ndarray, td: np.ndarray, am15: np.ndarray, h: float
                ) -> np.ndarray:
    """Activation at every step boundary, ``(T + 1, ...)``, from the excitation ``U``
    ``(T, ...)`` held per step: exact for each step's frozen time constant."""
    A = np.empty((U.shape[0] + 1,) + U.shape[1:])
    a = U[0].copy()                                   # steady state of the lead-in
    A[0] = a
    for k in range(U.shape[0]):
        uk = U[k]
        g = 0.5 + am15 * a
        tau = np.where(uk > a, ta * g, td / g)
        a = uk + (a - uk) * np.exp(-h / tau)
        A[k + 1] = a
    return A


def _rk4_affine(K0, C0, d0, Km, Cm, dm, K1, C1, d1, h):
    """One classical Runge-Kutta step of ``x' = v, v' = d - K x - C v`` (coefficients at
    the step's start, middle and end) written as the affine map ``y+ = Phi y + psi``:
    returns ``(P11, P12, P21, P22, q1, q2)``, vectorised over any shape.

    The step applied to ``y = (1, 0)`` and ``(0, 1)`` without forcing gives the columns of
    ``Phi``, to ``y = 0`` with the forcing ``psi``; written out with the zeros and ones
    of those inputs eliminated (``tests/analysis/muscle/test_dynamics.py`` holds it to the
    step-by-step form).
    """
    h2, h6 = 0.5 * h, h / 6.0
    # column 1: y = (1, 0)
    v2 = -h2 * K0
    k2v = -Km - Cm * v2
    v3 = h2 * k2v
    k3v = -Km * (1.0 + h2 * v2) - Cm * v3
    v4 = h * k3v
    k4v = -K1 * (1.0 + h * v3) - C1 * v4
    P11 = 1.0 + h6 * (2.0 * v2 + 2.0 * v3 + v4)
    P21 = h6 * (-K0 + 2.0 * k2v + 2.0 * k3v + k4v)
    # column 2: y = (0, 1)
    v2 = 1.0 - h2 * C0
    k2v = -Km * h2 - Cm * v2
    v3 = 1.0 + h2 * k2v
    k3v = -Km * (h2 * v2) - Cm * v3
    v4 = 1.0 + h * k3v
    k4v = -K1 * (h * v3) - C1 * v4
    P12 = h6 * (1.0 + 2.0 * v2 + 2.0 * v3 + v4)
    P22 = 1.0 + h6 * (-C0 + 2.0 * k2v + 2.0 * k3v + k4v)
    # forcing: y = 0
    v2 = h2 * d0
    k2v = dm - Cm * v2
    v3 = h2 * k2v
    k3v = dm - Km * (h2 * v2) - Cm * v3
    v4 = h * k3v
    k4v = d1 - K1 * (h * v3) - C1 * v4
    q1 = h6 * (2.0 * v2 + 2.0 * v3 + v4)
    q2 = h6 * (d0 + 2.0 * k2v + 2.0 * k3v + k4v)
    return P11, P12, P21, P22, q1, q2


def simulate_batch(theta: np.ndarray, rE: np.ndarray, sE: np.ndarray, dt_s: float
                   ) -> np.ndarray:
    """Sensor force of the twin for a batch of parameter sets and trials.

    Parameters
    ----------
    theta : ndarray, (P, 18)
        Physical parameters in :data:`PARAM_NAMES` order, one row per parameter set.
    rE : ndarray, (n_trials, n_steps)
        Commanded rE, held over each step; the first sample is the lead-in's 0.5 level.
    sE : ndarray, (n_trials,) or (n_trials, n_steps)
    dt_s : float
        Step, s.

    Returns
    -------
    ndarray, (P, n_trials, n_steps)
        Force ``x`` at the start of every step (before the step's input acts).

    Notes
    -----
    The activation is stepped first (the only non-linear recurrence: a few array
    operations per step); the mechanics are then linear with known time-varying
    coefficients, so each step's Runge-Kutta map is formed for all steps at once and only
    its affine recurrence runs step by step.
    """
    th = np.asarray(theta, float)[:, :, None]        # (P, 18, 1)
    Fe, Ff, ce, cf, we, wf, ta, td, wn0, z0, ke, kf, cs, ts, am = (th[:, k] for k in range(15))
    # th[:, 15], delay_s, is applied by the caller (a time shift of the stationary
    # model's output: see analysis.muscle.fit)
    the, thf = th[:, 16], th[:, 17]
    rE = np.asarray(rE, float)
    sE = np.asarray(sE, float)
    sE = sE[:, None] if sE.ndim == 1 else sE          # per trial, or per trial and step
    u_e = recruitment((rE * sE)[None], ce[..., None], we[..., None], the[..., None])
    u_f = recruitment(((1.0 - rE) * sE)[None], cf[..., None], wf[..., None], thf[..., None])
    P, n, T = u_e.shape
    # time first, so that each step reads a contiguous block
    U = np.ascontiguousarray(np.stack([u_e, u_f], axis=0).transpose(3, 0, 1, 2))  # (T,2,P,n)
    h = dt_s
    A = _activation(U, ta[None], td[None], 1.5 * am[None], h)      # (T+1, 2, P, n)
    # drive F_e a_e - F_f a_f and the relative active force phi; stiffness and damping of
    # active muscle grow with its force (short-range stiffness gamma F / L0; the
    # force-velocity slope F (1 + 1/A) / v_max), relative to the mean maximal force
    Fm = 0.5 * (Fe + Ff)
    D = Fe * A[:, 0] - Ff * A[:, 1]                                # (T+1, P, n)
    S = (Fe * A[:, 0] + Ff * A[:, 1]) / Fm
    Kx = (ke * Fe * A[:, 0] + kf * Ff * A[:, 1]) / Fm               # each muscle's own slope
    Dm, Sm = 0.5 * (D[1:] + D[:-1]), 0.5 * (S[1:] + S[:-1])        # activation linear
    Kxm = 0.5 * (Kx[1:] + Kx[:-1])
    w2 = wn0 ** 2
    c0 = 2.0 * z0 * wn0
    P11, P12, P21, P22, q1, q2 = _rk4_affine(
        w2 * (1 + Kx[:-1]), c0 + cs * S[:-1], w2 * D[:-1],
        w2 * (1 + Kxm), c0 + cs * Sm, w2 * Dm,
        w2 * (1 + Kx[1:]), c0 + cs * S[1:], w2 * D[1:], h)
    x = D[0] / (1.0 + Kx[0])                         # steady state of the lead-in
    v = np.zeros_like(x)
    X = np.empty((T, P, n))
    V = np.empty((T, P, n))
    for k in range(T):
        X[k] = x
        V[k] = v
        x, v = P11[k] * x + P12[k] * v + q1[k], P21[k] * x + P22[k] * v + q2[k]
    return (X + ts * V).transpose(1, 2, 0)
