"""The trial input: rE(t) (steady lead-in plus exponential chirp) and the two currents (pure).

rE(t) = rE_centre for ``steady_s``, then ``rE_centre + rE_amplitude sin(phi(t'))`` with
t' = t - steady_s and the exponential chirp phase

    phi(t') = 2 pi f0 T / ln(f1/f0) ((f1/f0)^(t'/T) - 1),

whose instantaneous frequency is f(t') = f0 (f1/f0)^(t'/T) (1 Hz -> 10 Hz over T = 10 s in
the paper). With ``input_kind = "multisine"`` the excitation is instead a periodic sum of
sines (period T = chirp_s, tones log-evenly spread over [f0, f1], low-crest phases) scaled
so that its peak is exactly ``rE_amplitude``: rE stays inside [rE_centre - amplitude,
rE_centre + amplitude] like the chirp, so the currents stay under Imax of the calibration
by construction. Each trial records its input as optional attributes (``input_kind``,
``input_json``: :func:`input_attrs`). The currents follow the paper's equations (1)-(4) inverted:
with Ie = rE sE and If = (1 - rE) sE,

    I'_e = Iemin + Ie (Iemax - Iemin),    I'_f = Ifmin + If (Ifmax - Ifmin).

Examples
--------
>>> import numpy as np
>>> float(chirp_frequency_Hz(np.array([0.0, 10.0]), 1.0, 10.0, 10.0)[1])
10.0
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmsid.protocols.config import InputKind, ProtocolConfig


def chirp_phase_rad(t_s, f0_Hz: float, f1_Hz: float, T_s: float) -> np.ndarray:
    """Phase of the exponential chirp at ``t_s`` seconds after the chirp starts."""
    t = np.asarray(t_s, dtype=float)
    k = f1_Hz / f0_Hz
    if math.isclose(k, 1.0):
        return 2 * np.pi * f0_Hz * t
    return 2 * np.pi * f0_Hz * T_s / math.log(k) * (np.power(k, t / T_s) - 1.0)


def chirp_frequency_Hz(t_s, f0_Hz: float, f1_Hz: float, T_s: float) -> np.ndarray:
    """Instantaneous frequency f(t) = f0 (f1/f0)^(t/T) (derivative of the phase / 2 pi)."""
    t = np.asarray(t_s, dtype=float)
    return f0_Hz * np.power(f1_Hz / f0_Hz, t / T_s)


def multisine_frequencies_Hz(f0_Hz: float, f1_Hz: float, period_s: float,
                             n_tones: int) -> np.ndarray:
    """``n_tones`` distinct harmonics of 1/period_s in [f0, f1], spread log-evenly.

    Log spacing puts as many tones per octave at the low end as at the high end, like the
    exponential chirp's equal time per octave.

    Raises
    ------
    ValueError
        If the band holds fewer than ``n_tones`` harmonics of 1/period_s.
    """
    k_lo = math.ceil(f0_Hz * period_s - 1e-9)
    k_hi = math.floor(f1_Hz * period_s + 1e-9)
    if k_hi - k_lo + 1 < n_tones or n_tones < 1:
        raise ValueError(f"{n_tones} tones do not fit: [{f0_Hz:g}, {f1_Hz:g}] Hz holds "
                         f"{max(k_hi - k_lo + 1, 0)} multiples of 1/{period_s:g} s")
    k = np.unique(np.round(np.geomspace(k_lo, k_hi, n_tones)).astype(int))
    if len(k) < n_tones:  # rounding merged neighbours at the low end: fill from below
        free = np.setdiff1d(np.arange(k_lo, k_hi + 1), k)
        k = np.sort(np.concatenate([k, free[:n_tones - len(k)]]))
    return k / period_s


def schroeder_phases_rad(frequencies_Hz, period_s: float) -> np.ndarray:
    """Schroeder (1970) phases for equal-amplitude tones at any frequencies.

    Each tone is given the group delay of a chirp sweeping the tones in order over the
    period (tone k "arrives" at k/K of it): phi_{k+1} = phi_k - 2 pi (f_{k+1} - f_k) T k/K.
    For consecutive harmonics this is Schroeder's phi_k = -pi k (k - 1) / K.
    """
    f = np.sort(np.asarray(frequencies_Hz, dtype=float))
    K = len(f)
    steps = -2 * np.pi * np.diff(f) * period_s * np.arange(1, K) / K
    return np.concatenate([[0.0], np.cumsum(steps)])


def low_crest_phases_rad(frequencies_Hz, period_s: float, iterations: int = 200
                        ) -> np.ndarray:
    """Phases that keep the peak of equal-amplitude tones low (deterministic).

    Starts from Schroeder phases and refines them by clipping iterations (Van der
    Ouderaa, Schoukens & Renneboog 1988): clip the signal of one period at 70 % of its
    peak, keep the phases of its spectrum at the tones, restore equal amplitudes; the
    lowest-crest iterate is returned. Needed because Schroeder's formula is optimal only
    for tones on a dense uniform grid; for log-spaced tones it leaves crest factors near 3.
    """
    f = np.sort(np.asarray(frequencies_Hz, dtype=float))
    k = np.round(f * period_s).astype(int)
    n = int(2 ** math.ceil(math.log2(max(64 * k.max(), 1024))))
    spec = np.zeros(n // 2 + 1, dtype=complex)
    phi = schroeder_phases_rad(f, period_s)
    best, best_crest = phi, math.inf
    for _ in range(iterations):
        spec[:] = 0
        spec[k] = np.exp(1j * (phi - np.pi / 2))        # sin(x + phi) = cos(x + phi - pi/2)
        x = np.fft.irfft(spec, n)
        crest = np.max(np.abs(x)) / np.sqrt(np.mean(x * x))
        if crest < best_crest:
            best, best_crest = phi.copy(), crest
        level = 0.7 * np.max(np.abs(x))
        phi = np.angle(np.fft.rfft(np.clip(x, -level, level))[k]) + np.pi / 2
    return best


def multisine_unit(t_s, frequencies_Hz, period_s: float) -> np.ndarray:
    """Sum of equal-amplitude sines with low-crest phases (:func:`low_crest_phases_rad`),
    shifted to start at an upward zero crossing and scaled to peak 1.

    A low crest factor (about 1.9-2.1 against 3-4 for random phases) fits more power under
    the same peak. The shift (a delay of a periodic signal: same spectrum) lets rE leave
    the steady lead-in without a step. The peak is found on a grid of 256 points per
    period of the highest tone (error < 1e-4) and kept 0.1 % under 1.
    """
    f = np.sort(np.asarray(frequencies_Hz, dtype=float))
    phi = low_crest_phases_rad(f, period_s)

    def raw(t):
        t = np.asarray(t, dtype=float)
        return np.sin(2 * np.pi * np.multiply.outer(t, f) + phi).sum(axis=-1)

    grid = np.linspace(0.0, period_s, max(4096, int(256 * f.max() * period_s)),
                       endpoint=False)
    g = raw(grid)
    up = np.nonzero((g[:-1] < 0) & (g[1:] >= 0))[0]
    shift = 0.0
    if len(up):
        i = up[0]
        shift = grid[i] + (grid[i + 1] - grid[i]) * (-g[i]) / (g[i + 1] - g[i])
    peak = float(np.max(np.abs(g))) * 1.001
    return raw(np.asarray(t_s, dtype=float) + shift) / peak


def excitation(p: ProtocolConfig, t_s) -> np.ndarray:
    """The unit excitation (values in [-1, 1]) ``t_s`` seconds after the lead-in ends."""
    if p.input_kind is InputKind.MULTISINE:
        f = multisine_frequencies_Hz(p.chirp_f0_Hz, p.chirp_f1_Hz, p.chirp_s,
                                     p.multisine_tones)
        return np.clip(multisine_unit(t_s, f, p.chirp_s), -1.0, 1.0)
    return np.sin(chirp_phase_rad(t_s, p.chirp_f0_Hz, p.chirp_f1_Hz, p.chirp_s))


def rE_signal(p: ProtocolConfig) -> np.ndarray:
    """rE for one trial sampled at ``p.fs_Hz``: sample k at k / fs_Hz s after onset."""
    n = p.n_samples
    t = np.arange(n) / p.fs_Hz
    rE = np.full(n, p.rE_centre, dtype=float)
    chirp = t >= p.steady_s - 1e-12
    tc = t[chirp] - p.steady_s
    rE[chirp] = p.rE_centre + p.rE_amplitude * excitation(p, tc)
    # rounding can push 0.5 + 0.5 sin just outside [0, 1]
    return np.clip(rE, 0.0, 1.0)


def input_attrs(p: ProtocolConfig) -> dict[str, str]:
    """Optional trial attributes that describe the input beyond the paper's chirp ones.

    ``input_kind`` is ``"chirp"`` or ``"multisine"``; ``input_json`` holds every setting
    needed to regenerate rE (for a multisine the tone frequencies too). The contract's
    ``chirp_s``, ``chirp_f0_Hz``, ``chirp_f1_Hz`` keep their meaning for a chirp and are the
    excitation's length and band for any other input.
    """
    d: dict[str, Any] = {"kind": p.input_kind.value, "steady_s": p.steady_s,
                         "duration_s": p.chirp_s, "f0_Hz": p.chirp_f0_Hz, "f1_Hz": p.chirp_f1_Hz,
                         "rE_centre": p.rE_centre, "rE_amplitude": p.rE_amplitude}
    if p.input_kind is InputKind.MULTISINE:
        d["phases"] = "low_crest"
        d["tones_Hz"] = [float(v) for v in multisine_frequencies_Hz(
            p.chirp_f0_Hz, p.chirp_f1_Hz, p.chirp_s, p.multisine_tones)]
    return {"input_kind": p.input_kind.value, "input_json": json.dumps(d, sort_keys=True)}


def currents_mA(rE, sE: float, Iemin_mA: float, Iemax_mA: float, Ifmin_mA: float,
                Ifmax_mA: float) -> tuple[np.ndarray, np.ndarray]:
    """Extensor and flexor carrier amplitudes for a given rE(t) at constant sE.

    Inverts the paper's equations (1)-(4): Ie = rE sE, If = (1 - rE) sE, then
    I' = Imin + I (Imax - Imin) per muscle.

    Returns
    -------
    I_ext_mA, I_flex_mA : ndarray
    """
    rE = np.asarray(rE, dtype=float)
    Ie = rE * sE
    If = (1.0 - rE) * sE
    return (Iemin_mA + Ie * (Iemax_mA - Iemin_mA),
            Ifmin_mA + If * (Ifmax_mA - Ifmin_mA))


@dataclass(frozen=True, eq=False)
class TrialWaveform:
    """One trial's commanded signals, before the interlock checks them."""

    sE: float
    rE: np.ndarray
    I_ext_mA: np.ndarray
    I_flex_mA: np.ndarray
    fs_Hz: float
    carrier_Hz: float

    @property
    def n_samples(self) -> int:
        return len(self.rE)


def trial_waveform(p: ProtocolConfig, sE: float, calibration) -> TrialWaveform:
    """The waveform of one identification trial at ``sE``.

    Parameters
    ----------
    p : ProtocolConfig
    sE : float
        The EAA sum held during the trial, in (0, 1].
    calibration : protocols.session_file.Calibration or any object with Iemin_mA, Iemax_mA,
        Ifmin_mA, Ifmax_mA
    """
    if not 0 < sE <= 1:
        raise ValueError(f"sE = {sE!r} is outside (0, 1]")
    rE = rE_signal(p)
    I_ext, I_flex = currents_mA(rE, sE, calibration.Iemin_mA, calibration.Iemax_mA,
                                calibration.Ifmin_mA, calibration.Ifmax_mA)
    return TrialWaveform(sE=float(sE), rE=rE, I_ext_mA=I_ext, I_flex_mA=I_flex,
                         fs_Hz=p.fs_Hz, carrier_Hz=p.carrier_Hz)
