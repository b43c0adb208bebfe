"""An independent muscle formulation: compliant-tendon Hill muscles on a fixture (issue 20).

Written apart from MuJoCo's muscles and from the physiological twin
(:mod:`nmsid.analysis.muscle.dynamics`) so that the twin is checked against physics it was not
written with. Differences on purpose:

- recruitment: a power law above a threshold, ``u = a_max ((I - I_th) / (1 - I_th))^g``
  (no sigmoid);
- activation: Zajac 1989's bilinear form ``a' = (u - a) (u / tau_act + (1 - u) / tau_deact)``
  (the rate depends on the excitation, not on the activation);
- contraction: fibre length as a state, Gaussian force-length
  ``fl = exp(-((l - 1) / 0.45)^2)`` (Thelen 2003's shape), exponential passive force, and the
  Hill force-velocity hyperbola inverted for the fibre velocity (Zajac 1989's
  equilibrium model; eccentric branch with a 1.5 F0 asymptote, as in Millard et al.
  2013's curve), a small fibre damping (Millard's damped model) keeping it defined at
  low activation;
- a compliant, non-linear tendon (toe region, then linear: 1 F0 at 3.3 % strain,
  Zajac 1989) in series with each fibre;
- the forearm's inertia on a spring-damper fixture; the sensor reads the spring force
  plus 15 % of the damper's.

Simulated by explicit Euler at 4 kHz (sub-steps of the session's rate: the tendon is
stiff); sessions are recorded at 1 kHz to keep the simulation short. Everything is
vectorised over trials.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.protocols.session_file import Session, Trial


@dataclass(frozen=True)
class HillParticipant:
    """Parameters of the independent formulation (defaults: a mid-sized elbow)."""

    F0_e_N: float = 900.0
    F0_f_N: float = 1100.0
    r_e_m: float = 0.02
    r_f_m: float = 0.03
    l_opt_e_m: float = 0.10
    l_opt_f_m: float = 0.12
    l_slack_e_m: float = 0.19
    l_slack_f_m: float = 0.20
    l_rest_e: float = 0.95
    """Fibre length at rest in optimal lengths."""
    l_rest_f: float = 1.05
    v_max_lopt_s: float = 10.0
    I_th_e: float = 0.08
    I_th_f: float = 0.05
    gamma_e: float = 1.6
    gamma_f: float = 1.3
    a_max_e: float = 0.12
    a_max_f: float = 0.10
    tau_act_s: float = 0.012
    tau_deact_s: float = 0.045
    J_kgm2: float = 0.065
    K_fix_Nm_rad: float = 30.0
    zeta_fix: float = 0.35
    sensed_damping: float = 0.15
    lever_m: float = 0.22
    noise_N: float = 0.02
    gain_scatter: float = 0.0
    """Relative SD of a per-trial scale of ``a_max`` (electrode contact between trials)."""


def _fl(l):
    return np.exp(-((l - 1.0) / 0.45) ** 2)


def _fpe(l):
    return np.where(l > 1.0, 0.05 * np.expm1(5.0 * (l - 1.0)), 0.0)


def _tendon(eps):
    """Normalised tendon force: toe region below 1.27 % strain, then linear (1 F0 at 3.3 %)."""
    toe = 0.0127
    k_lin = 1.0 / (0.033 - toe / 2)
    return np.where(eps <= 0, 0.0, np.where(eps < toe, k_lin * eps ** 2 / (2 * toe),
                                            k_lin * (eps - toe / 2)))


def _fibre_velocity(f, a_fl, v_max):
    """Lengthening velocity (optimal lengths/s) from the Hill hyperbola inverted: ``f`` is
    the force the fibre must carry relative to ``a fl`` (A = 0.25 concentric; eccentric to
    1.5)."""
    f = np.clip(f, 0.0, 1.45)
    conc = -v_max * (1.0 - f) / (1.0 + f / 0.25)
    ecc = v_max * (f - 1.0) / (2.0 * (1.5 - f))
    return np.where(f < 1.0, conc, ecc)


def simulate(p: HillParticipant, rE: np.ndarray, sE: np.ndarray, fs_Hz: float,
             rng: np.random.Generator) -> np.ndarray:
    """(n_trials, n) sensor force for commanded rE (n_trials, n) at levels sE (n_trials,)."""
    n_tr, n = rE.shape
    sub = max(1, int(round(4000.0 / fs_Hz)))
    h = 1.0 / (fs_Hz * sub)
    sE = np.asarray(sE, float)[:, None]
    scale = 1.0 + p.gain_scatter * rng.standard_normal(n_tr)

    def recruit(I, th, g, amax):
        x = np.clip((I - th) / (1 - th), 0.0, 1.0)
        return np.minimum(amax * scale[:, None] * x ** g, 1.0)
    u_e = recruit(rE * sE, p.I_th_e, p.gamma_e, p.a_max_e)
    u_f = recruit((1 - rE) * sE, p.I_th_f, p.gamma_f, p.a_max_f)
    F0 = np.array([p.F0_e_N, p.F0_f_N])[:, None]
    r = np.array([p.r_e_m, -p.r_f_m])[:, None]          # extension positive
    lopt = np.array([p.l_opt_e_m, p.l_opt_f_m])[:, None]
    lsl = np.array([p.l_slack_e_m, p.l_slack_f_m])[:, None]
    B = 2 * p.zeta_fix * np.sqrt(p.K_fix_Nm_rad * p.J_kgm2)
    # musculotendon length at q = 0 so that the relaxed tendon is at slack + a small strain
    lm = np.array([p.l_rest_e, p.l_rest_f])[:, None] * np.ones((2, n_tr))
    lmt0 = lm * lopt + lsl * 1.002
    q = np.zeros(n_tr)
    w = np.zeros(n_tr)
    a = np.stack([u_e[:, 0], u_f[:, 0]])
    out = np.empty((n_tr, n))
    beta = 0.05
    for k in range(n):
        u = np.stack([u_e[:, k], u_f[:, k]])
        for _ in range(sub):
            lmt = lmt0 - r * q                                   # extensor shortens as q grows
            eps = (lmt - lm * lopt) / lsl - 1.0
            Ft = _tendon(eps)                                    # in F0
            a_fl = np.maximum(a, 0.005) * _fl(lm)
            f = (Ft - _fpe(lm)) / a_fl
            v = _fibre_velocity(f, a_fl, p.v_max_lopt_s)
            v = v + (Ft - _fpe(lm) - a_fl * np.clip(f, 0, 1.45)) / beta   # damped residual
            lm = lm + h * v
            tau_rate = u / p.tau_act_s + (1 - u) / p.tau_deact_s
            a = a + h * (u - a) * tau_rate
            torque = np.sum(r * Ft * F0, axis=0)
            acc = (torque - p.K_fix_Nm_rad * q - B * w) / p.J_kgm2
            q = q + h * w
            w = w + h * acc
        out[:, k] = (p.K_fix_Nm_rad * q + p.sensed_damping * B * w) / p.lever_m
    return out + p.noise_N * rng.standard_normal(out.shape)


def session(p: HillParticipant, *, levels=None, repeats: int = 3, seed: int = 0,
            chirp_s: float = 10.0, steady_s: float = 5.0, fs_Hz: float = 1000.0) -> Session:
    """A session of the paper's protocol (in memory) on this formulation."""
    from nmsid.analysis.design.candidates import paper_candidate
    from nmsid.protocols.waveforms import input_attrs, rE_signal

    cand = paper_candidate()
    cfg = cand.config()
    proto = cfg.protocol
    import dataclasses
    proto = dataclasses.replace(proto, chirp_s=chirp_s, steady_s=steady_s, fs_Hz=fs_Hz)
    levels = tuple(levels) if levels is not None else tuple(proto.sE_levels)
    rE = rE_signal(proto)
    rng = np.random.default_rng(seed)
    plan = [(s, rpt) for rpt in range(1, repeats + 1) for s in levels]
    rows = np.vstack([rE] * len(plan))
    force = simulate(p, rows, np.array([s for s, _ in plan]), proto.fs_Hz, rng)
    trials = []
    for k, (s, rpt) in enumerate(plan):
        trials.append(Trial(sE=float(s), repeat=rpt, fs_Hz=proto.fs_Hz, rE=rE,
                            I_ext_mA=2.0 + rE * s * 8.0, I_flex_mA=2.0 + (1 - rE) * s * 8.0,
                            force_N=force[k], steady_s=proto.steady_s, chirp_s=proto.chirp_s,
                            chirp_f0_Hz=proto.chirp_f0_Hz, chirp_f1_Hz=proto.chirp_f1_Hz,
                            carrier_Hz=proto.carrier_Hz, name=f"t{k + 1:03d}",
                            extra_attrs=dict(input_attrs(proto))))
    return Session(path="<hill participant>", participant="HILL", created_utc="",
                   software="bench/hill_participant.py", calibration=None, trials=trials,
                   config_json=cfg.to_json())
