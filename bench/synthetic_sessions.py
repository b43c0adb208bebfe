"""Synthetic session files with known second-order parameters (for tests and benchmarks).

Each trial: ``steady_s`` s at rE = 0.5, then an exponential chirp
``rE = 0.5 + 0.5 sin(phi)``, ``phi(t) = 2 pi f0 T / ln(f1/f0) ((f1/f0)^(t/T) - 1)``.
The force is the exact response of ``Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)`` to rE - 0.5
(system at rest at stimulation onset), computed on a 10x finer grid with the analytic
chirp (independent of the estimator's own discretisation), plus what a real force sensor
adds: white noise, 50 Hz mains pick-up, an offset and a linear drift, all drawn per trial.

Parameters vary with sE along curves whose shape (linear, quadratic, exponential,
saturating) and range are drawn from the seed, within Kp 2-15 N, wn 8-60 rad/s,
zeta 0.2-1.2, so that no estimator can be tuned to one generator shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import cont2discrete, lfilter

from nmsid.protocols.session_file import Calibration, SessionWriter, Trial

SE_LEVELS = tuple(round(0.30 + 0.05 * i, 2) for i in range(15))
RANGES = {"Kp": (2.0, 15.0), "wn_rad_s": (8.0, 60.0), "zeta": (0.2, 1.2)}
SHAPES = ("linear", "quadratic", "exponential", "saturating")


@dataclass
class SyntheticTruth:
    """The known parameters of a synthetic session, per sE."""

    participant: str
    sE: list[float]
    Kp: list[float]
    wn_rad_s: list[float]
    zeta: list[float]
    shapes: dict[str, str] = field(default_factory=dict)
    noise_sd_N: float = 0.04

    def at(self, sE: float) -> tuple[float, float, float]:
        i = int(np.argmin(np.abs(np.asarray(self.sE) - sE)))
        return self.Kp[i], self.wn_rad_s[i], self.zeta[i]


def _curve(rng: np.random.Generator, name: str, sE: np.ndarray) -> tuple[np.ndarray, str]:
    lo, hi = RANGES[name]
    a, b = np.sort(rng.uniform(lo, hi, 2))
    if rng.random() < 0.5:
        a, b = b, a                       # decreasing as often as increasing
    x = (sE - sE.min()) / (sE.max() - sE.min())
    shape = SHAPES[int(rng.integers(len(SHAPES)))]
    if shape == "linear":
        g = x
    elif shape == "quadratic":
        c = rng.uniform(0.2, 0.8)             # extremum inside the range
        g = (x - c) ** 2 / max(c, 1 - c) ** 2
        g = 1 - g if rng.random() < 0.5 else g
    elif shape == "exponential":
        k = rng.uniform(1.0, 3.0)
        g = (np.exp(k * x) - 1) / (np.exp(k) - 1)
    else:
        k = rng.uniform(2.0, 5.0)
        g = (1 - np.exp(-k * x)) / (1 - np.exp(-k))
    return a + (b - a) * g, shape


def chirp_rE(t_s: np.ndarray, steady_s: float, chirp_s: float, f0_Hz: float,
             f1_Hz: float) -> np.ndarray:
    """rE(t): 0.5 during the lead-in, then the exponential chirp."""
    tc = np.clip(t_s - steady_s, 0.0, None)
    phi = 2 * np.pi * f0_Hz * chirp_s / math.log(f1_Hz / f0_Hz) * \
        ((f1_Hz / f0_Hz) ** (tc / chirp_s) - 1)
    return np.where(t_s < steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))


def exact_response(Kp: float, wn: float, zeta: float, fs_Hz: float, n: int, steady_s: float,
                   chirp_s: float, f0_Hz: float, f1_Hz: float,
                   oversample: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(rE, force without noise) sampled at fs_Hz; simulated on a finer grid."""
    fine = fs_Hz * oversample
    t_fine = np.arange(n * oversample) / fine
    r_fine = chirp_rE(t_fine, steady_s, chirp_s, f0_Hz, f1_Hz)
    b, a, _ = cont2discrete(([Kp * wn * wn], [1.0, 2 * zeta * wn, wn * wn]), 1 / fine,
                            method="foh")
    y_fine = lfilter(np.ravel(b), a, r_fine - 0.5)
    return r_fine[::oversample].copy(), y_fine[::oversample].copy()


def write_synthetic_session(path: str | Path, seed: int = 0, *, participant: str | None = None,
                            sE_levels=SE_LEVELS, repeats: int = 3, fs_Hz: float = 2000.0,
                            steady_s: float = 5.0, chirp_s: float = 10.0, f0_Hz: float = 1.0,
                            f1_Hz: float = 10.0, noise_sd_N: float | None = None,
                            mains_N: float | None = None, params=None,
                            noise_seed: int | None = None) -> SyntheticTruth:
    """Write a session file with known parameters and return them.

    Parameters
    ----------
    path : path-like
        Where to write (must not exist).
    seed : int
        Draws the parameter curves, their shapes and the sensor's noise levels.
    params : dict of sE -> (Kp, wn, zeta), optional
        Explicit parameters instead of drawn curves.
    noise_seed : int, optional
        Seed of the noise only (default: ``seed``); lets a benchmark redraw noise on
        fixed parameters.
    """
    rng = np.random.default_rng(seed)
    sE = np.asarray(sE_levels, dtype=float)
    shapes = {}
    if params is None:
        curves = {}
        for name in ("Kp", "wn_rad_s", "zeta"):
            curves[name], shapes[name] = _curve(rng, name, sE)
        kp, wn, zeta = curves["Kp"], curves["wn_rad_s"], curves["zeta"]
    else:
        kp = np.array([params[x][0] for x in sE_levels])
        wn = np.array([params[x][1] for x in sE_levels])
        zeta = np.array([params[x][2] for x in sE_levels])
    sd = float(noise_sd_N if noise_sd_N is not None else rng.uniform(0.02, 0.06))
    mains = float(mains_N if mains_N is not None else rng.uniform(0.01, 0.05))
    noise_rng = np.random.default_rng(seed if noise_seed is None else noise_seed + 10_000)
    participant = participant or f"SYN{seed:03d}"
    n = int(round((steady_s + chirp_s) * fs_Hz))
    t = np.arange(n) / fs_Hz
    w = SessionWriter.create(path, participant=participant, seed=seed, backend="synthetic")
    cal = Calibration(Iemin_mA=2.0, Iemax_mA=9.5, Ifmin_mA=1.5, Ifmax_mA=8.0)
    w.write_calibration(cal)
    responses = {}
    for i, s in enumerate(sE):
        responses[i] = exact_response(kp[i], wn[i], zeta[i], fs_Hz, n, steady_s, chirp_s,
                                      f0_Hz, f1_Hz)
    order = [(i, r) for r in range(1, repeats + 1) for i in range(len(sE))]
    order = [order[j] for j in rng.permutation(len(order))]
    done = {i: 0 for i in range(len(sE))}
    for i, _ in order:
        done[i] += 1
        rE, y = responses[i]
        force = (y + noise_rng.normal(0.0, sd, n)
                 + mains * np.sin(2 * np.pi * 50 * t + noise_rng.uniform(0, 2 * np.pi))
                 + noise_rng.uniform(-1.0, 1.0) + noise_rng.uniform(-0.03, 0.03) * t)
        Ie, If = rE * sE[i], (1 - rE) * sE[i]
        w.append_trial(Trial(
            sE=float(sE[i]), repeat=done[i], fs_Hz=fs_Hz, rE=rE,
            I_ext_mA=cal.Iemin_mA + Ie * (cal.Iemax_mA - cal.Iemin_mA),
            I_flex_mA=cal.Ifmin_mA + If * (cal.Ifmax_mA - cal.Ifmin_mA),
            force_N=force, steady_s=steady_s, chirp_s=chirp_s, chirp_f0_Hz=f0_Hz,
            chirp_f1_Hz=f1_Hz, started_utc="2026-11-22T01:30:00Z"))
    return SyntheticTruth(participant=participant, sE=[float(x) for x in sE],
                          Kp=[float(x) for x in kp], wn_rad_s=[float(x) for x in wn],
                          zeta=[float(x) for x in zeta], shapes=shapes, noise_sd_N=sd)
