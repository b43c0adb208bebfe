"""Sessions with trial-to-trial physiology, written independently of nmsid's simulator.

Each trial is the exact response of ``Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)`` to
``rE - 0.5`` computed by ``scipy.signal.lsim`` (continuous state space, linear
interpolation of the input) on a grid 4x finer than the record, the chirp evaluated
analytically (``rE = 0.5 + 0.5 sin(phi)``, ``phi = 2 pi f0 T / ln(f1/f0) ((f1/f0)^(t/T)
- 1)``); nothing of nmsid's discretisation, simulator or waveforms is used. Per trial:

* Kp, wn and zeta are the level's values times ``exp(N(0, cv))`` (independent draws);
* fatigue multiplies the gain by ``g(c)``, ``c`` the cumulative stimulation at the trial,
  linear (``1 - p c / C``) or exponential (``(1 - p)^(c / C)``) in ``C``, the session's
  total stimulation, so that ``p`` is the loss over the session;
* optional library effects: a dead time (the force moved later by ``dead_time_s``), a
  first-order activation lag (``activation_tau_s``), or a
  saturating output (``s tanh(f / s)`` with ``s`` set so that the largest level's peak is
  compressed by ``saturation_pct``);
* the sensor: white noise, 50 Hz mains, an offset and a drift per trial.

Reference trials (a fixed sE repeated through the session) are supported by passing a
schedule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from nmsid.protocols.session_file import Calibration, SessionWriter, Trial

FS_HZ = 1000.0
STEADY_S = 5.0
CHIRP_S = 10.0


@dataclass
class TrialPhysiology:
    """What a session of :func:`write_session` is made of."""

    levels: tuple[float, ...] = tuple(np.round(np.linspace(0.3, 1.0, 15), 2))
    repeats: int = 3
    cv: tuple[float, float, float] = (0.10, 0.05, 0.05)
    """Trial-to-trial scatter of Kp, wn, zeta (SD of the log)."""
    fatigue_pct: float = 0.0
    fatigue_shape: str = "linear"
    dead_time_s: float = 0.0
    activation_tau_s: float = 0.0
    """A first-order activation lag before the second-order dynamics (s; 0: none)."""
    saturation_pct: float = 0.0
    noise_N: float = 0.03
    fs_Hz: float = FS_HZ
    steady_s: float = STEADY_S
    chirp_s: float = CHIRP_S
    randomisation: str = "blocks"
    """``blocks`` (each repeat of every level in a shuffled block) or ``full``."""
    truth: dict = field(default_factory=dict)


def level_curves(sE: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-level Kp (N), wn (rad/s), zeta along drawn smooth curves."""
    x = (sE - sE.min()) / max(sE.max() - sE.min(), 1e-9)
    kp = rng.uniform(2.0, 4.0) + rng.uniform(4.0, 10.0) * x ** rng.uniform(0.7, 1.6)
    wn = rng.uniform(15.0, 30.0) + rng.uniform(5.0, 20.0) * x
    zeta = rng.uniform(0.4, 0.7) + rng.uniform(-0.15, 0.25) * x
    return kp, wn, zeta


def chirp(t: np.ndarray, steady_s: float, chirp_s: float, f0=1.0, f1=10.0) -> np.ndarray:
    tc = np.clip(t - steady_s, 0.0, None)
    phi = 2 * np.pi * f0 * chirp_s / np.log(f1 / f0) * ((f1 / f0) ** (tc / chirp_s) - 1)
    return np.where(t < steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))


def response(Kp: float, wn: float, zeta: float, t: np.ndarray, u: np.ndarray,
             tau_s: float = 0.0) -> np.ndarray:
    """Exact second-order response to ``u`` (at rest at t = 0, input linear between
    samples): scipy's first-order-hold discretisation of the continuous state space (what
    ``scipy.signal.lsim`` computes), run as a filter. ``tau_s > 0`` puts a first-order
    activation lag ``1 / (tau s + 1)`` before it."""
    if tau_s > 0:
        A = np.array([[0.0, 1.0, 0.0], [-wn * wn, -2 * zeta * wn, Kp * wn * wn],
                      [0.0, 0.0, -1.0 / tau_s]])
        B, C = np.array([[0.0], [0.0], [1.0 / tau_s]]), np.array([[1.0, 0.0, 0.0]])
    else:
        A = np.array([[0.0, 1.0], [-wn * wn, -2 * zeta * wn]])
        B, C = np.array([[0.0], [Kp * wn * wn]]), np.array([[1.0, 0.0]])
    D = np.zeros((1, 1))
    ad, bd, cd, dd, _ = signal.cont2discrete((A, B, C, D), float(t[1] - t[0]), method="foh")
    b, a = signal.ss2tf(ad, bd, cd, dd)
    return signal.lfilter(np.ravel(b), a, u)


def schedule(levels, repeats: int, rng, how: str = "blocks", reference=None,
             every: int = 0) -> list[tuple[float, int]]:
    """(sE, repeat) in running order; optional reference trials every ``every`` trials."""
    order: list[tuple[float, int]] = []
    if how == "blocks":
        for r in range(1, repeats + 1):
            order += [(float(levels[j]), r) for j in rng.permutation(len(levels))]
    else:
        pairs = [(float(s), r) for r in range(1, repeats + 1) for s in levels]
        order = [pairs[j] for j in rng.permutation(len(pairs))]
        seen: dict[float, int] = {}
        fixed = []
        for s, _ in order:                      # repeat numbers in running order
            seen[s] = seen.get(s, 0) + 1
            fixed.append((s, seen[s]))
        order = fixed
    if reference is not None and every > 0:
        out, k = [], 0
        for i, item in enumerate(order):
            if i % every == 0:
                k += 1
                out.append((float(reference), 100 + k))
            out.append(item)
        order = out
    return order


def write_session(path, phys: TrialPhysiology, seed: int, *, reference=None, every: int = 0,
                  participant: str = "TS") -> TrialPhysiology:
    """Write one session; ``phys.truth`` receives the drawn per-trial parameters."""
    rng = np.random.default_rng([seed, 2911])
    levels = np.asarray(phys.levels, dtype=float)
    all_levels = np.unique(np.append(levels, reference)) if reference is not None else levels
    kp, wn, zeta = level_curves(all_levels, rng)
    order = schedule(levels, phys.repeats, rng, phys.randomisation, reference, every)
    fs = phys.fs_Hz
    n = round((phys.steady_s + phys.chirp_s) * fs)
    t = np.arange(n) / fs
    up = 4
    tf = np.arange(n * up) / (fs * up)
    uf = chirp(tf, phys.steady_s, phys.chirp_s) - 0.5
    rE = chirp(t, phys.steady_s, phys.chirp_s)
    dur = n / fs
    total = dur * len(order)
    sat_s = None
    if phys.saturation_pct > 0:
        j = int(np.argmax(kp))
        peak = float(np.max(np.abs(response(kp[j], wn[j], zeta[j], tf, uf))))
        x = np.linspace(0.1, 20.0, 4000)
        c = phys.saturation_pct / 100.0
        sat_s = peak * x[np.argmin(np.abs(x * np.tanh(1 / x) - (1 - c)))]
    w = SessionWriter.create(path, participant=participant, seed=seed, backend="synthetic")
    cal = Calibration(Iemin_mA=2.0, Iemax_mA=9.5, Ifmin_mA=1.5, Ifmax_mA=8.0)
    w.write_calibration(cal)
    trials = []
    p = phys.fatigue_pct / 100.0
    for k, (sE, rep) in enumerate(order):
        j = int(np.argmin(np.abs(all_levels - sE)))
        d = np.exp(rng.normal(0.0, phys.cv))
        c_centre = k * dur + phys.steady_s + phys.chirp_s / 2
        if phys.fatigue_shape == "linear":
            g = 1.0 - p * c_centre / total
        else:
            g = (1.0 - p) ** (c_centre / total)
        K, W, Z = kp[j] * d[0] * g, wn[j] * d[1], zeta[j] * d[2]
        yf = response(K, W, Z, tf, uf, phys.activation_tau_s)
        if phys.dead_time_s > 0:
            shift = round(phys.dead_time_s * fs * up)
            yf = np.concatenate([np.zeros(shift), yf[:-shift]])
        if sat_s is not None:
            yf = sat_s * np.tanh(yf / sat_s)
        y = yf[::up]
        force = (y + rng.normal(0.0, phys.noise_N, n)
                 + 0.02 * np.sin(2 * np.pi * 50 * t + rng.uniform(0, 2 * np.pi))
                 + rng.uniform(-1.0, 1.0) + rng.uniform(-0.02, 0.02) * t)
        w.append_trial(Trial(sE=float(sE), repeat=int(rep), fs_Hz=fs, rE=rE,
                             I_ext_mA=cal.Iemin_mA + rE * sE * (cal.Iemax_mA - cal.Iemin_mA),
                             I_flex_mA=cal.Ifmin_mA + (1 - rE) * sE * (cal.Ifmax_mA
                                                                       - cal.Ifmin_mA),
                             force_N=force, steady_s=phys.steady_s, chirp_s=phys.chirp_s,
                             started_utc="2026-11-22T01:30:00Z"))
        trials.append({"sE": sE, "repeat": rep, "Kp": K, "wn": W, "zeta": Z, "gain": g})
    phys.truth = {"trials": trials, "total_stim_s": total, "loss_pct": phys.fatigue_pct}
    return phys
