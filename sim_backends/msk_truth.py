"""Ground truth for the musculoskeletal participant: its best second-order description.

The musculoskeletal participant is not a second-order system (activation dynamics with
different rise and fall time constants, sigmoid recruitment, Hill-type force-length-
velocity, spill-over, a mount with a sensed damper). What identification *should* find
per sE is the best second-order approximation of its noise-free response to the paper's
trial: ``G(s) = Kp wn^2 / (s^2 + 2 zeta wn s + wn^2)`` from rE to the force, fitted by
output error over the chirp window, the way the identification treats data
(``analysis.settings.IdentificationSettings`` defaults: linear detrend of the whole trial,
Savitzky-Golay 41/3 and a 4th-order 25 Hz Butterworth run forwards and backwards on force
and rE alike, window ``steady_s`` to the end, initial state, offset and ramp estimated with
the model). ``fit_pct`` says how much of the response a second-order model can explain at
all: the ceiling for any identification of that level.

The fit here is independent of ``analysis`` (a lower layer may not import it): variable
projection over (ln wn, ln zeta), Kp / initial state / offset / ramp by least squares for
each, first-order-hold discretisation at the raw rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nmsid.protocols.config import ProtocolConfig
from nmsid.protocols.waveforms import trial_waveform
from nmsid.sim_backends.msk_simulation import MskSimulator

SAVGOL_WINDOW = 41
SAVGOL_ORDER = 3
LOWPASS_HZ = 25.0
BUTTER_ORDER = 4
END_TRIM_S = 0.25
"""Samples this close to the record's end are filter edges and are not fitted."""


@dataclass(frozen=True)
class SecondOrderTruth:
    """The best second-order description of the participant at one sE."""

    sE: float
    Kp: float
    """Gain, N per unit rE."""
    wn_rad_s: float
    zeta: float
    fit_pct: float
    """``100 (1 - ||y - yhat|| / ||y - mean y||)`` of the noise-free response: what a
    second-order model can explain at this sE."""
    offset_N: float
    """Mean force of the noise-free response over the window (tared at rest)."""


def quantise_mA(I_mA: np.ndarray, step_mA: float = 1e-3) -> np.ndarray:
    """What the stimulator delivers: the request rounded down to its 1 uA step."""
    return np.floor(np.asarray(I_mA) / step_mA + 1e-6) * step_mA


def _signal():
    """``scipy.signal``, imported on first use: it costs 0.5-1 s, and a simulated session
    imports this module (through the participant models) without asking for a truth."""
    from scipy import signal
    return signal


def _preprocess(x: np.ndarray, fs_Hz: float) -> np.ndarray:
    signal = _signal()
    y = signal.savgol_filter(x, SAVGOL_WINDOW, SAVGOL_ORDER, axis=-1)
    sos = signal.butter(BUTTER_ORDER, LOWPASS_HZ, fs=fs_Hz, output="sos")
    return signal.sosfiltfilt(sos, y, axis=-1)


def _model_columns(u: np.ndarray, wn: float, zeta: float, dt: float) -> np.ndarray:
    """Columns whose span is the model output: unit-gain response to u, two free
    responses (initial state), constant, ramp."""
    signal = _signal()
    num, den = [wn * wn], [1.0, 2.0 * zeta * wn, wn * wn]
    b, a, _ = signal.cont2discrete((num, den), dt, method="foh")
    b = np.ravel(b)
    n = u.size
    g = signal.lfilter(b, a, u)
    e = np.zeros(n)
    e[0] = 1.0
    h1 = signal.lfilter([1.0], a, e)
    h2 = np.concatenate([[0.0], h1[:-1]])
    t = np.linspace(-1.0, 1.0, n)
    return np.column_stack([g, h1, h2, np.ones(n), t])


def fit_second_order_reference(u: np.ndarray, y: np.ndarray, fs_Hz: float
                               ) -> tuple[float, float, float, float]:
    """Output-error fit of ``Kp wn^2/(s^2 + 2 zeta wn s + wn^2)`` (free initial state,
    offset, ramp) to preprocessed ``u`` (rE minus its mean) and ``y``.

    Returns
    -------
    Kp, wn_rad_s, zeta, fit_pct
    """
    dt = 1.0 / fs_Hz
    ys = y - y.mean()

    def resid(p):
        X = _model_columns(u, math.exp(p[0]), math.exp(p[1]), dt)
        theta, *_ = np.linalg.lstsq(X, y, rcond=None)
        return y - X @ theta

    q = max(1, int(fs_Hz // 200))          # coarse start on a decimated copy
    best: tuple[float, float, float] | None = None
    for wn in np.geomspace(4.0, 120.0, 11):
        for z in np.geomspace(0.12, 3.0, 8):
            X = _model_columns(u[::q], wn, z, dt * q)
            theta, *_ = np.linalg.lstsq(X, y[::q], rcond=None)
            r = float(np.sum((y[::q] - X @ theta) ** 2))
            if best is None or r < best[0]:
                best = (r, float(wn), float(z))
    assert best is not None  # the grid above is not empty
    from scipy import optimize  # lazy, as _signal(): only a truth's fit needs it
    sol = optimize.least_squares(resid, [math.log(best[1]), math.log(best[2])],
                                 x_scale=[0.1, 0.1], xtol=1e-12, ftol=1e-14, gtol=1e-14)
    wn, z = math.exp(sol.x[0]), math.exp(sol.x[1])
    X = _model_columns(u, wn, z, dt)
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    fit = 100.0 * (1.0 - np.linalg.norm(y - X @ theta) / np.linalg.norm(ys))
    return float(theta[0]), wn, z, float(fit)


@lru_cache(maxsize=512)
def _truth_cached(participant, sE: float, currents: tuple[float, float, float, float],
                  protocol: ProtocolConfig, fs_Hz: float) -> SecondOrderTruth:
    class _Cal:
        Iemin_mA, Iemax_mA, Ifmin_mA, Ifmax_mA = currents
    wf = trial_waveform(protocol, sE, _Cal)
    sim = MskSimulator(participant, fs_Hz)
    y = sim.simulate(quantise_mA(wf.I_ext_mA), quantise_mA(wf.I_flex_mA)).true_force_N
    n = y.size
    t = np.arange(n)
    y_d = y - np.polyval(np.polyfit(t, y, 1), t)      # the identification's detrend
    both = _preprocess(np.vstack([y_d, wf.rE]), fs_Hz)
    i0 = int(round(protocol.steady_s * fs_Hz))
    i1 = n - int(round(END_TRIM_S * fs_Hz))
    yw, rw = both[0, i0:i1], both[1, i0:i1]
    Kp, wn, z, fit = fit_second_order_reference(rw - rw.mean(), yw, fs_Hz)
    return SecondOrderTruth(sE=float(sE), Kp=Kp, wn_rad_s=wn, zeta=z, fit_pct=fit,
                            offset_N=float(np.mean(y[i0:i1])))


def second_order_truth(participant, sE: float, calibration,
                       protocol: ProtocolConfig | None = None) -> SecondOrderTruth:
    """The best second-order description of ``participant`` at ``sE`` (cached).

    Parameters
    ----------
    participant : MskParticipant
    sE : float
        The trial's EAA sum, in (0, 1].
    calibration
        Any object with ``Iemin_mA``, ``Iemax_mA``, ``Ifmin_mA``, ``Ifmax_mA``: the
        currents the session used.
    protocol : ProtocolConfig, optional
        The trial's timing and chirp (default: the paper's).
    """
    cur = tuple(float(getattr(calibration, n))
                for n in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA"))
    p = protocol or ProtocolConfig()
    return _truth_cached(participant, round(float(sE), 9), cur, p, float(p.fs_Hz))
