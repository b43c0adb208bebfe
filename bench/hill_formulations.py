"""Other Hill-type muscle formulations for the muscle twin's bench (issue 29, item 4).

Beside ``bench/hill_participant.py`` (Zajac 1989 style: compliant tendon, bilinear
activation), three formulations from the literature, each written from its paper's
equations and independent of the twin (:mod:`nmsid.analysis.muscle.dynamics`) and of
MuJoCo. They share the participant's geometry, recruitment and fixture
(:class:`hill_participant.HillParticipant`) so that only the muscle model differs:

``thelen2003`` (Thelen 2003, J Biomech Eng 125:70; rigid tendon as OpenSim's
    ``Thelen2003Muscle`` with ``ignore_tendon_compliance``): activation
    ``a' = (u - a) / tau`` with ``tau = tau_act (0.5 + 1.5 a)`` rising and
    ``tau_deact / (0.5 + 1.5 a)`` falling; force-length ``exp(-(l - 1)^2 / 0.45)``;
    passive ``(exp(4 (l - 1) / 0.6) - 1) / (exp(4) - 1)``; force-velocity Thelen's
    hyperbola (Af = 0.25) concentric, eccentric rising smoothly from 1 to its asymptote
    1.4, with ``v_max = 10 l_opt/s``.
``degroote2016`` (De Groote, Kinney, Rao & Fregly 2016, Ann Biomed Eng 44:2922; compliant
    tendon): smooth activation ``a' = (f / (tau_a (0.5 + 1.5 a)) + (1 - f)(0.5 + 1.5 a) /
    tau_d) (u - a)``, ``f = (tanh(10 (u - a)) + 1) / 2``; force-length the sum of three
    Gaussian-like terms with the paper's coefficients; force-velocity
    ``d1 ln(d2 v + d3 + sqrt((d2 v + d3)^2 + 1)) + d4`` inverted in closed form;
    tendon ``0.2 exp(35 (l_t - 0.995)) - 0.2`` (their kT = 35, shifted to rest at slack).
``millard2012`` (Millard, Uchida, Seth & Delp 2013, J Biomech Eng 135:021005, the
    rigid-tendon equilibrium model): first-order activation with constant time
    constants (10 / 40 ms); force-length a broad smooth bell (zero at 0.44 and 1.8
    optimal lengths, as Millard's quintic Bezier curve; here a raised cosine in log
    length), passive force reaching 1 F0 at 1.7 l_opt, force-velocity with the
    concentric curvature of Millard's default (0.3 at half v_max) and an eccentric
    plateau of 1.4.

Simulated by explicit Euler at 4 kHz, recorded at 1 kHz, vectorised over trials.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from hill_participant import HillParticipant

from nmsid.protocols.session_file import Session, Trial

FORMULATIONS = ("thelen2003", "degroote2016", "millard2012")


# -- curves -----------------------------------------------------------------------------
def fl_thelen(l):
    return np.exp(-((l - 1.0) ** 2) / 0.45)


def fpe_thelen(l):
    return np.where(l > 1.0, np.expm1(4.0 * (l - 1.0) / 0.6) / np.expm1(4.0), 0.0)


def fv_thelen(v):
    """Thelen's force-velocity (v in v_max units, shortening negative)."""
    af, flen = 0.25, 1.4
    conc = (1.0 + v) / (1.0 - v / af)
    ecc = (flen * v + 0.1) / (v + 0.1)          # 1 at v = 0, rising to flen
    return np.where(v <= 0, np.maximum(conc, 0.0), ecc)


_DG_B = ((0.815, 1.055, 0.162, 0.063), (0.433, 0.717, -0.030, 0.200),
         (0.100, 1.000, 0.354, 0.000))
_DG_D = (-0.318, -8.149, -0.374, 0.886)


def fl_degroote(l):
    out = np.zeros_like(l)
    for b1, b2, b3, b4 in _DG_B:
        out = out + b1 * np.exp(-0.5 * (l - b2) ** 2 / (b3 + b4 * l) ** 2)
    return out


def fpe_degroote(l):
    kpe, e0 = 4.0, 0.6
    return np.maximum((np.exp(kpe * (l - 1.0) / e0) - 1.0) / (np.exp(kpe) - 1.0), 0.0)


def fv_degroote_inverse(f):
    """Normalised velocity (v_max units) at which the fibre produces ``f`` (a fl units)."""
    d1, d2, d3, d4 = _DG_D
    return (np.sinh((np.clip(f, 0.0, 1.75) - d4) / d1) - d3) / d2


def tendon_degroote(lt):
    return np.maximum(0.2 * np.exp(35.0 * (lt - 0.995)) - 0.2, 0.0)


def fl_millard(l):
    x = np.log(np.clip(l, 1e-3, None))
    lo, hi = np.log(0.44), np.log(1.8)
    left = 0.5 * (1 + np.cos(np.pi * np.clip(x / lo, 0, 1)))
    right = 0.5 * (1 + np.cos(np.pi * np.clip(x / hi, 0, 1)))
    return np.where(x < 0, left, right)


def fpe_millard(l):
    return np.where(l > 1.0, ((l - 1.0) / 0.7) ** 2, 0.0)


def fv_millard(v):
    conc = (1.0 + v) / (1.0 - v / 0.3)
    ecc = 1.0 + 0.4 * np.tanh(4.0 * v)
    return np.where(v <= 0, np.maximum(conc, 0.0), ecc)


# -- simulation -------------------------------------------------------------------------
def simulate(p: HillParticipant, form: str, rE: np.ndarray, sE: np.ndarray, fs_Hz: float,
             rng: np.random.Generator) -> np.ndarray:
    """(n_trials, n) sensor force of formulation ``form`` (see module)."""
    if form not in FORMULATIONS:
        raise ValueError(f"formulation {form!r}: use one of {FORMULATIONS}")
    n_tr, n = rE.shape
    sub = max(1, round(4000.0 / fs_Hz))
    h = 1.0 / (fs_Hz * sub)
    sE = np.asarray(sE, float)[:, None]

    def recruit(current, th, g, amax):
        x = np.clip((current - th) / (1 - th), 0.0, 1.0)
        return np.minimum(amax * x ** g, 1.0)
    u_e = recruit(rE * sE, p.I_th_e, p.gamma_e, p.a_max_e)
    u_f = recruit((1 - rE) * sE, p.I_th_f, p.gamma_f, p.a_max_f)
    F0 = np.array([p.F0_e_N, p.F0_f_N])[:, None]
    r = np.array([p.r_e_m, -p.r_f_m])[:, None]
    lopt = np.array([p.l_opt_e_m, p.l_opt_f_m])[:, None]
    lsl = np.array([p.l_slack_e_m, p.l_slack_f_m])[:, None]
    vmax = p.v_max_lopt_s
    B = 2 * p.zeta_fix * np.sqrt(p.K_fix_Nm_rad * p.J_kgm2)
    lm = np.array([p.l_rest_e, p.l_rest_f])[:, None] * np.ones((2, n_tr))
    lmt0 = lm * lopt + lsl * 1.002
    q = np.zeros(n_tr)
    w = np.zeros(n_tr)
    a = np.stack([u_e[:, 0], u_f[:, 0]])
    out = np.empty((n_tr, n))
    for k in range(n):
        u = np.stack([u_e[:, k], u_f[:, k]])
        for _ in range(sub):
            lmt = lmt0 - r * q
            if form == "thelen2003":
                tau = np.where(u > a, 0.015 * (0.5 + 1.5 * a), 0.050 / (0.5 + 1.5 * a))
                a = a + h * (u - a) / tau
                lm = (lmt - lsl) / lopt                           # rigid tendon
                v = -(r * w) / lopt / vmax
                Ft = a * fl_thelen(lm) * fv_thelen(v) + fpe_thelen(lm)
            elif form == "millard2012":
                tau = np.where(u > a, 0.010, 0.040)
                a = a + h * (u - a) / tau
                lm = (lmt - lsl) / lopt
                v = -(r * w) / lopt / vmax
                Ft = a * fl_millard(lm) * fv_millard(v) + fpe_millard(lm)
            else:                                                 # degroote2016
                f = 0.5 * np.tanh(10.0 * (u - a)) + 0.5
                c = 0.5 + 1.5 * a
                a = a + h * (f / (0.015 * c) + (1 - f) * c / 0.060) * (u - a)
                lt = (lmt - lm * lopt) / lsl
                Ft = tendon_degroote(lt)
                a_fl = np.maximum(a, 0.005) * fl_degroote(lm)
                need = (Ft - fpe_degroote(lm)) / a_fl
                v = fv_degroote_inverse(need)
                v = v + (Ft - fpe_degroote(lm) - a_fl * np.clip(need, 0.0, 1.75)) / 0.05
                lm = lm + h * v * vmax
            torque = np.sum(r * Ft * F0, axis=0)
            acc = (torque - p.K_fix_Nm_rad * q - B * w) / p.J_kgm2
            q = q + h * w
            w = w + h * acc
        out[:, k] = (p.K_fix_Nm_rad * q + p.sensed_damping * B * w) / p.lever_m
    return out + p.noise_N * rng.standard_normal(out.shape)


def session(p: HillParticipant, form: str, *, levels=None, repeats: int = 3, seed: int = 0,
            chirp_s: float = 10.0, steady_s: float = 5.0, fs_Hz: float = 1000.0) -> Session:
    """A session of the paper's protocol (in memory) on formulation ``form``."""
    from nmsid.analysis.design.candidates import paper_candidate
    from nmsid.protocols.waveforms import input_attrs, rE_signal

    cfg = paper_candidate().config()
    proto = dataclasses.replace(cfg.protocol, chirp_s=chirp_s, steady_s=steady_s, fs_Hz=fs_Hz)
    levels = tuple(levels) if levels is not None else tuple(proto.sE_levels)
    rE = rE_signal(proto)
    rng = np.random.default_rng([seed, FORMULATIONS.index(form)])
    plan = [(s, rpt) for rpt in range(1, repeats + 1) for s in levels]
    force = simulate(p, form, np.vstack([rE] * len(plan)), np.array([s for s, _ in plan]),
                     proto.fs_Hz, rng)
    trials = [Trial(sE=float(s), repeat=rpt, fs_Hz=proto.fs_Hz, rE=rE,
                    I_ext_mA=2.0 + rE * s * 8.0, I_flex_mA=2.0 + (1 - rE) * s * 8.0,
                    force_N=force[k], steady_s=proto.steady_s, chirp_s=proto.chirp_s,
                    chirp_f0_Hz=proto.chirp_f0_Hz, chirp_f1_Hz=proto.chirp_f1_Hz,
                    carrier_Hz=proto.carrier_Hz, name=f"t{k + 1:03d}",
                    extra_attrs=dict(input_attrs(proto)))
              for k, (s, rpt) in enumerate(plan)]
    return Session(path=f"<{form}>", participant=form.upper(), created_utc="",
                   software="bench/hill_formulations.py", calibration=None, trials=trials,
                   config_json=cfg.to_json())
