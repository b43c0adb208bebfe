"""Synthetic session files with known answers, for tests, benchmarks and examples.

Two generators, both written independently of the analysis code (their own chirp and
discretisation), so that a test does not check the code against itself:

* :func:`write_synthetic_session`: known second-order parameters per sE, drawn curves
  (identification and QC).
* :func:`write_gap_session`: one fixed participant with effects the gap diagnosis should
  (or should not) name: a dead time, fatigue, a tremor outside its candidates.

:func:`write_synthetic_session`

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
from scipy.signal import butter, cont2discrete, lfilter, sosfiltfilt

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
                            noise_seed: int | None = None,
                            extra_attrs: dict | None = None) -> SyntheticTruth:
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
    extra_attrs : dict, optional
        Optional root attributes (e.g. a joint's, ``protocols.joints.joint_attrs``).
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
    w = SessionWriter.create(path, participant=participant, seed=seed, backend="synthetic",
                             extra_attrs=extra_attrs)
    cal = Calibration(Iemin_mA=2.0, Iemax_mA=9.5, Ifmin_mA=1.5, Ifmax_mA=8.0)
    w.write_calibration(cal)
    responses = {}
    for i in range(len(sE)):
        responses[i] = exact_response(kp[i], wn[i], zeta[i], fs_Hz, n, steady_s, chirp_s,
                                      f0_Hz, f1_Hz)
    order = [(i, r) for r in range(1, repeats + 1) for i in range(len(sE))]
    order = [order[j] for j in rng.permutation(len(order))]
    done = dict.fromkeys(range(len(sE)), 0)
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


# -- sessions for the gap diagnosis ----------------------------------------------------

GAP_FS_HZ = 2000.0


def gap_true_params(sE):
    """(Kp, wn_rad_s, zeta) of :func:`write_gap_session`'s participant at ``sE``."""
    Kp = 1.2 * np.exp(1.5 * sE)
    wn = 30 + 35 * sE - 15 * sE ** 2
    zeta = 0.45 + 0.35 * sE
    return Kp, wn, zeta


def write_gap_session(path, *, levels=(0.3, 0.5, 0.7, 0.9, 1.0), repeats=3, seed=0,
                      dead_time_s=0.0, noise_N=0.04, blocks=True, fatigue_per_100s=0.0,
                      hold=True, step=None, bump=None, tremor=None, co_contraction=None,
                      steady_s=5.0,
                      chirp_s=10.0, fs_Hz=GAP_FS_HZ):
    """Write a session of a fixed second-order participant with chosen effects.

    The force is scipy's exact discretisation of ``Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)``
    (:func:`gap_true_params`) driven by ``rE - 0.5``, plus 50 Hz mains pick-up, white
    noise, a per-trial offset and drift.

    Parameters
    ----------
    path : path-like
        Where to write (must not exist).
    levels, repeats : sequence of float, int
        The sE levels and repeats per level.
    seed : int
        Draws the trial order and the noise.
    dead_time_s : float
        The force answers the drive this late (whole samples).
    noise_N : float
        Standard deviation of the sensor's white noise, N.
    blocks : bool
        Repeats of a level run back to back (levels in random order); False: the whole
        order is shuffled.
    fatigue_per_100s : float
        The gain falls linearly with cumulative stimulation, by this fraction per 100 s.
    hold : bool
        The stimulator holds each sample (zero-order hold, exact); False: the stimulation
        is the smooth signal the record samples (first-order hold).
    step : (int, float, float), optional
        ``(k, t_s, height_N)``: a baseline step in the k-th trial written.
    bump : (sequence of int, float, float, float), optional
        ``(ks, t_s, duration_s, height_N)``: a voluntary contraction in those trials.
    tremor : (float, float), optional
        ``(f_Hz, rms_N)``: a physiological tremor (white noise through a resonator
        0.8 Hz wide) added to every trial with that RMS scaled by sE; no candidate of the
        gap diagnosis models it (but it differs between repeats, so it mostly raises
        the noise floor).
    co_contraction : (float, float), optional
        ``(gain_N, tau_s)``: both muscles pulling at once when they share the drive,
        ``gain_N sE (4 rE (1 - rE) - 1)`` through a first-order lag ``tau_s``. Even in
        ``rE - 0.5`` (twice the chirp's frequency), so no candidate of the gap diagnosis
        (each odd in the drive) explains it: a repeatable unexplained gap.
    steady_s, chirp_s, fs_Hz : float
        Trial timing: lead-in at rE = 0.5, then a 1-10 Hz exponential chirp.

    Returns
    -------
    path-like
        ``path``.
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
    n = int(round((steady_s + chirp_s) * fs_Hz))
    t = np.arange(n) / fs_Hz
    rE = chirp_rE(t, steady_s, chirp_s, 1.0, 10.0)
    cum_s = 0.0
    for k_trial, (sE, rep) in enumerate(order):
        Kp, wn, zeta = gap_true_params(sE)
        # exact for the stimulator's zero-order hold (each sample held for 1/fs)
        b, a, _ = cont2discrete(([Kp * wn ** 2], [1, 2 * zeta * wn, wn ** 2]), 1 / fs_Hz,
                                method="zoh" if hold else "foh")
        u = rE - 0.5
        if dead_time_s > 0:
            k = int(round(dead_time_s * fs_Hz))
            u = np.concatenate([np.zeros(k), u[:-k]])
        y = lfilter(np.ravel(b), np.ravel(a), u)
        if step is not None and step[0] == k_trial:
            y = y + step[2] * (t >= step[1])
        if bump is not None and k_trial in bump[0]:
            m = (t >= bump[1]) & (t < bump[1] + bump[2])
            y = y + bump[3] * m * np.sin(np.pi * (t - bump[1]) / bump[2]) ** 2
        y = y * (1.0 - fatigue_per_100s * (cum_s + t) / 100.0)
        cum_s += len(t) / fs_Hz
        if co_contraction is not None:
            both = 4 * rE * (1 - rE) - 1.0        # 0 when one muscle has all the drive
            lag = np.exp(-1 / (co_contraction[1] * fs_Hz))
            y = y + co_contraction[0] * sE * lfilter([1 - lag], [1, -lag], both)
        if tremor is not None:
            y = y + sE * _resonant_noise(rng, n, tremor[0], 0.8, tremor[1], fs_Hz)
        noise = noise_N * rng.standard_normal(n) + 0.03 * np.sin(2 * np.pi * 50 * t)
        force = y + noise + 0.3 * rng.standard_normal() + 0.01 * rng.standard_normal() * t
        I_e = 2.0 + rE * sE * 7.0
        I_f = 1.5 + (1 - rE) * sE * 6.5
        w.append_trial(Trial(sE=float(sE), repeat=rep, fs_Hz=fs_Hz, rE=rE, I_ext_mA=I_e,
                             I_flex_mA=I_f, force_N=force, steady_s=steady_s,
                             chirp_s=chirp_s))
    return path


def _resonant_noise(rng, n, f_Hz, width_Hz, rms, fs_Hz):
    """White noise through a resonator (AR(2)) at ``f_Hz``, scaled to ``rms``."""
    r = np.exp(-np.pi * width_Hz / fs_Hz)
    th = 2 * np.pi * f_Hz / fs_Hz
    x = lfilter([1.0], [1.0, -2 * r * np.cos(th), r * r], rng.standard_normal(n + 4000))[4000:]
    return rms * x / np.std(x)


# -- sessions with trial-to-trial physiology and library effects -----------------------

PHYS_LEVELS = tuple(round(0.30 + 0.05 * i, 2) for i in range(15))


def _unit_sigmoid(slope: float, mid: float):
    return lambda u: 1.0 / (1.0 + np.exp(-slope * (np.asarray(u, float) - mid)))


def recruitment_curve(spec):
    """``h(u)`` of a recruitment spec: None (linear), ``("sigmoid", slope, midpoint)``,
    ``("power", gamma)`` or ``("threshold", threshold, saturation)`` (linear between)."""
    if spec is None:
        return lambda u: np.asarray(u, float)
    kind = spec[0]
    if kind == "sigmoid":
        return _unit_sigmoid(float(spec[1]), float(spec[2]))
    if kind == "power":
        g = float(spec[1])
        return lambda u: np.clip(np.asarray(u, float), 0.0, None) ** g
    if kind == "threshold":
        lo, hi = float(spec[1]), float(spec[2])
        return lambda u: np.clip((np.asarray(u, float) - lo) / (hi - lo), 0.0, 1.0)
    raise ValueError(f"recruitment {spec!r}: sigmoid, power or threshold")


def fatigue_gain(shape: str, loss: float, x, tau_frac: float = 0.2):
    """Gain left after the fraction ``x`` of the session's stimulation: ``linear``
    ``1 - p x``, ``exponential`` ``(1 - p)^x``, ``saturating``
    ``1 - p (1 - exp(-x / tau)) / (1 - exp(-1 / tau))`` (``tau`` a fraction of the
    session): all lose ``p`` by the session's end."""
    x = np.asarray(x, float)
    if shape == "linear":
        return 1.0 - loss * x
    if shape == "exponential":
        return (1.0 - loss) ** x
    if shape == "saturating":
        return 1.0 - loss * -np.expm1(-x / tau_frac) / -np.expm1(-1.0 / tau_frac)
    raise ValueError(f"fatigue shape {shape!r}: linear, exponential or saturating")


def _second_order(K, wn, zeta, dt):
    b, a, _ = cont2discrete(([K * wn ** 2], [1.0, 2 * zeta * wn, wn ** 2]), dt, method="foh")
    return np.ravel(b), np.ravel(a)


def write_physiology_session(path, *, seed: int = 0, levels=PHYS_LEVELS, repeats: int = 3,
                             cv=(0.10, 0.05, 0.05), noise_N: float = 0.03,
                             randomisation: str = "blocks", recruitment=None,
                             asymmetry=None, dead_time_s: float = 0.0,
                             activation_tau_s: float = 0.0, fatigue=None, drift=None,
                             step=None, steady_s: float = 5.0, chirp_s: float = 10.0,
                             fs_Hz: float = 1000.0, participant: str = "P01") -> dict:
    """A session of two antagonist muscles with trial-to-trial scatter and library effects,
    written independently of nmsid's simulator and analysis.

    The extensor is driven by ``u_e = sE rE``, the flexor by ``u_f = sE (1 - rE)``; each
    passes its recruitment curve ``h`` (deviation from its lead-in value) and its own
    second-order dynamics (scipy's first-order-hold discretisation on a 4x finer grid,
    the chirp analytic); the force is their difference, normalised so that the small-signal
    gain at each sE is the level's ``Kp``. Level curves are drawn from the seed
    (Kp 2-14 N, wn 15-50 rad/s, zeta 0.4-0.9); every trial's Kp, wn and zeta are the
    level's times ``exp(N(0, cv))``.

    Parameters
    ----------
    path : path-like
        New file.
    seed : int
    levels, repeats : sequence of float, int
    cv : (float, float, float)
        Trial-to-trial scatter of Kp, wn, zeta (SD of the log).
    noise_N : float
        White sensor noise; 50 Hz pick-up, an offset and a linear drift per trial too.
    randomisation : {"blocks", "full"}
    recruitment : tuple, optional
        :func:`recruitment_curve`'s spec (a library effect: recruitment non-linearity).
    asymmetry : (float, float), optional
        ``(wn_ratio, zeta_ratio)`` of the flexor against the extensor.
    dead_time_s, activation_tau_s : float
        A dead time; a first-order activation lag before each muscle's dynamics.
    fatigue : (str, float) or (str, float, float), optional
        ``(shape, loss, tau_frac)``: :func:`fatigue_gain` at each trial's centre.
    drift : (float, float), optional
        ``(rms_N, corner_Hz)``: a slow baseline wander in every trial (white noise through
        a zero-phase 4th-order Butterworth low-pass at ``corner_Hz``).
    step : (int, float, float), optional
        ``(k, t_s, height_N)``: a baseline step in the k-th trial written.

    Returns
    -------
    dict
        The truth: per-trial parameters, fatigue gains, total stimulation and loss.
    """
    rng = np.random.default_rng([seed, 4040])
    lv = np.asarray(levels, float)
    x = (lv - lv.min()) / max(float(np.ptp(lv)), 1e-9)
    kp = rng.uniform(2.0, 4.0) + rng.uniform(4.0, 10.0) * x ** rng.uniform(0.7, 1.5)
    wn = rng.uniform(15.0, 28.0) + rng.uniform(5.0, 20.0) * x
    zeta = rng.uniform(0.4, 0.6) + rng.uniform(-0.1, 0.25) * x
    order = [(j, r) for r in range(1, repeats + 1) for j in range(len(lv))]
    if randomisation == "blocks":
        order = [(int(j), r) for r in range(1, repeats + 1)
                 for j in rng.permutation(len(lv))]
    else:
        order = [order[i] for i in rng.permutation(len(order))]
    n = int(round((steady_s + chirp_s) * fs_Hz))
    up = 4
    t = np.arange(n) / fs_Hz
    tf = np.arange(n * up) / (fs_Hz * up)

    def chirp(tt):
        tc = np.clip(tt - steady_s, 0.0, None)
        phi = 2 * np.pi * chirp_s / np.log(10.0) * (10.0 ** (tc / chirp_s) - 1)
        return np.where(tt < steady_s, 0.5, 0.5 + 0.5 * np.sin(phi))

    rE, rEf = chirp(t), chirp(tf)
    h = recruitment_curve(recruitment)
    dt = 1.0 / (fs_Hz * up)
    total = n / fs_Hz * len(order)
    w = SessionWriter.create(path, participant=participant, seed=seed, backend="synthetic")
    cal = Calibration(Iemin_mA=2.0, Iemax_mA=9.5, Ifmin_mA=1.5, Ifmax_mA=8.0)
    w.write_calibration(cal)
    truth: list[dict] = []
    for k, (j, rep) in enumerate(order):
        sE = float(lv[j])
        d = np.exp(rng.normal(0.0, cv))
        K, W, Z = kp[j] * d[0], wn[j] * d[1], zeta[j] * d[2]
        centre = (k * n / fs_Hz + steady_s + 0.5 * chirp_s) / total
        g = 1.0
        if fatigue is not None:
            g = float(fatigue_gain(fatigue[0], fatigue[1], centre,
                                   *(fatigue[2:3] if len(fatigue) > 2 else ())))
        half = h(0.5 * sE)
        eps = 1e-4
        slope = float(h(0.5 * sE + eps) - h(0.5 * sE - eps)) / (2 * eps)
        norm = 2.0 * sE * slope if slope > 0 else 1.0
        xe, xf = h(sE * rEf) - half, h(sE * (1 - rEf)) - half
        if activation_tau_s > 0:
            a = np.exp(-dt / activation_tau_s)
            xe, xf = (lfilter([1 - a], [1, -a], v) for v in (xe, xf))
        be, ae = _second_order(1.0, W, Z, dt)
        wr, zr = asymmetry if asymmetry is not None else (1.0, 1.0)
        bf, af = _second_order(1.0, W * wr, Z * zr, dt)
        yf = K * g * (lfilter(be, ae, xe) - lfilter(bf, af, xf)) / norm
        if dead_time_s > 0:
            sh = int(round(dead_time_s * fs_Hz * up))
            yf = np.concatenate([np.zeros(sh), yf[:-sh]])
        y = yf[::up]
        if drift is not None:        # white noise through a 4th-order low-pass
            sos = butter(2, drift[1], fs=fs_Hz, output="sos")
            wander = sosfiltfilt(sos, rng.standard_normal(n + 20000))[10000:-10000]
            y = y + drift[0] * wander / max(float(np.std(wander)), 1e-12)
        if step is not None and step[0] == k:
            y = y + step[2] * (t >= step[1])
        force = (y + rng.normal(0.0, noise_N, n)
                 + 0.02 * np.sin(2 * np.pi * 50 * t + rng.uniform(0, 2 * np.pi))
                 + rng.uniform(-1.0, 1.0) + rng.uniform(-0.02, 0.02) * t)
        w.append_trial(Trial(sE=sE, repeat=int(rep), fs_Hz=fs_Hz, rE=rE,
                             I_ext_mA=cal.Iemin_mA + rE * sE * (cal.Iemax_mA - cal.Iemin_mA),
                             I_flex_mA=cal.Ifmin_mA + (1 - rE) * sE * (cal.Ifmax_mA
                                                                       - cal.Ifmin_mA),
                             force_N=force, steady_s=steady_s, chirp_s=chirp_s,
                             started_utc="2026-11-22T01:30:00Z"))
        truth.append({"sE": sE, "repeat": rep, "Kp": K, "wn": W, "zeta": Z, "gain": g})
    return {"trials": truth, "total_stim_s": total,
            "loss_pct": 100.0 * fatigue[1] if fatigue is not None else 0.0}
