"""The trial input: rE(t) (steady lead-in plus exponential chirp) and the two currents (pure).

rE(t) = rE_centre for ``steady_s``, then ``rE_centre + rE_amplitude sin(phi(t'))`` with
t' = t - steady_s and the exponential chirp phase

    phi(t') = 2 pi f0 T / ln(f1/f0) ((f1/f0)^(t'/T) - 1),

whose instantaneous frequency is f(t') = f0 (f1/f0)^(t'/T) (1 Hz -> 10 Hz over T = 10 s in
the paper). The currents follow the paper's equations (1)-(4) inverted: with
Ie = rE sE and If = (1 - rE) sE,

    I'_e = Iemin + Ie (Iemax - Iemin),    I'_f = Ifmin + If (Ifmax - Ifmin).

Examples
--------
>>> import numpy as np
>>> float(chirp_frequency_Hz(np.array([0.0, 10.0]), 1.0, 10.0, 10.0)[1])
10.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.config import ProtocolConfig


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


def chirp_time_s(f_Hz, f0_Hz: float, f1_Hz: float, T_s: float) -> np.ndarray:
    """Time after the chirp start at which the instantaneous frequency is ``f_Hz``."""
    f = np.asarray(f_Hz, dtype=float)
    return T_s * np.log(f / f0_Hz) / math.log(f1_Hz / f0_Hz)


def rE_signal(p: ProtocolConfig) -> np.ndarray:
    """rE for one trial sampled at ``p.fs_Hz``: sample k at k / fs_Hz s after onset."""
    n = p.n_samples
    t = np.arange(n) / p.fs_Hz
    rE = np.full(n, p.rE_centre, dtype=float)
    chirp = t >= p.steady_s - 1e-12
    tc = t[chirp] - p.steady_s
    rE[chirp] = p.rE_centre + p.rE_amplitude * np.sin(
        chirp_phase_rad(tc, p.chirp_f0_Hz, p.chirp_f1_Hz, p.chirp_s))
    # rounding can push 0.5 + 0.5 sin just outside [0, 1]
    return np.clip(rE, 0.0, 1.0)


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


def normalised_from_currents(I_ext_mA, I_flex_mA, Iemin_mA: float, Iemax_mA: float,
                             Ifmin_mA: float, Ifmax_mA: float):
    """The paper's equations (1)-(4) forward: (Ie, If, rE, sE) from the applied currents."""
    Ie = (np.asarray(I_ext_mA, dtype=float) - Iemin_mA) / (Iemax_mA - Iemin_mA)
    If = (np.asarray(I_flex_mA, dtype=float) - Ifmin_mA) / (Ifmax_mA - Ifmin_mA)
    sE = Ie + If
    with np.errstate(invalid="ignore", divide="ignore"):
        rE = np.where(sE != 0, Ie / np.where(sE != 0, sE, 1.0), np.nan)
    return Ie, If, rE, sE


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
