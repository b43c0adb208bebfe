"""Literature values of the physiological twin's parameters: starting points, bounds and
the weak priors that hold what the paper's protocol cannot determine.

Each prior is log-normal (on the fitted scale) with a wide spread: it only decides a
parameter the data leave open, and the fit reports which ones those were.

- ``tau_act_s`` 15 ms, ``tau_deact_s`` 50 ms: Thelen 2003 ("Adjustment of muscle mechanics
  model parameters to simulate dynamic contractions in older adults", J Biomech Eng
  125:70), within Winters 1995's ranges (activation 5-20 ms, deactivation 20-70 ms;
  "An improved muscle-reflex actuator for use in large-scale neuromusculoskeletal models",
  Ann Biomed Eng 23:359). Spread x2.5 (ln 0.9): FES recruits synchronously and the
  twitch of stimulated human arm muscle is slower than voluntary activation.
- ``c_s_per_s``: Hill's force-velocity slope at zero velocity, ``(1 + 1/A) / v_max`` with
  ``A = 0.25`` and ``v_max`` 10 optimal lengths/s (Zajac 1989, "Muscle and tendon:
  properties, models, scaling...", Crit Rev Biomed Eng 17:359; Millard et al. 2013,
  J Biomech Eng 135:021005) expressed through the fixture: a few s^-1 per unit
  activation; spread x5.
- ``k_s``: stiffness of active muscle per unit activation relative to the mount's; short
  range stiffness ``gamma F / L0`` with ``gamma`` about 23 (Cui et al. 2008, J Biomech
  41:1945) against a strap-and-cuff mount a few times stiffer: about 0.5; spread x5.
- recruitment midpoint ``c`` 0.5, width ``w`` 0.2 of the calibrated range (Crago, Peckham &
  Thrope 1980, IEEE TBME 27:679; Durfee & MacLean 1989, IEEE TBME 36:654: the
  calibration spans threshold to near-saturation); spread 0.4 and x3.
- ``a_max``, the share of each muscle the electrode reaches at full intensity: 0.1
  (surface FES at tolerable currents reaches the superficial fibres only; e.g. Mesin et
  al. 2010), spread x4.
- the forces, ``wn0``, ``zeta0`` and the sensor's zero ``sensor_zero_s`` (the share of the
  mount's damping force the cell reads, e.g. 20 % of ``2 zeta0 / wn0``) have no prior:
  the session determines them.
"""

from __future__ import annotations

import math

import numpy as np

from nmsid.analysis.muscle.dynamics import PARAM_NAMES

#: (start, lower, upper, log-scale, prior sd on the fitted scale or None) per parameter.
TABLE = {
    "F_e_N": (5.0, 1e-3, 1e4, True, None),
    "F_f_N": (5.0, 1e-3, 1e4, True, None),
    "c_e": (0.5, -1.0, 2.0, False, 0.4),
    "c_f": (0.5, -1.0, 2.0, False, 0.4),
    "w_e": (0.2, 0.02, 2.0, True, math.log(3.0)),
    "w_f": (0.2, 0.02, 2.0, True, math.log(3.0)),
    "tau_act_s": (0.015, 0.001, 0.3, True, 0.9),
    "tau_deact_s": (0.05, 0.002, 0.5, True, 0.9),
    "wn0_rad_s": (25.0, 3.0, 300.0, True, None),
    "zeta0": (0.5, 0.02, 5.0, True, None),
    "k_e": (0.1, -0.45, 20.0, False, 1.0),
    "k_f": (0.1, -0.45, 20.0, False, 1.0),
    "c_s_per_s": (5.0, 1e-2, 500.0, True, math.log(5.0)),
    "sensor_zero_s": (0.005, 1e-5, 0.1, True, None),
    "a_max": (0.1, 0.005, 1.0, True, math.log(4.0)),
    "delay_s": (0.0, -0.02, 0.05, False, 0.01),
    "th_e": (0.0, -0.3, 0.6, False, 0.15),
    "th_f": (0.0, -0.3, 0.6, False, 0.15),
}

LOG = np.array([TABLE[n][3] for n in PARAM_NAMES])
PRIOR_SD = np.array([TABLE[n][4] if TABLE[n][4] is not None else np.inf
                     for n in PARAM_NAMES])


def to_z(theta: np.ndarray) -> np.ndarray:
    """Physical parameters -> the fitted scale (log for the positive ones)."""
    th = np.asarray(theta, float)
    return np.where(LOG, np.log(np.maximum(th, 1e-300)), th)


def to_theta(z: np.ndarray) -> np.ndarray:
    """The fitted scale -> physical parameters (works on stacked rows)."""
    z = np.asarray(z, float)
    return np.where(LOG, np.exp(z), z)


def start_theta() -> np.ndarray:
    """The literature starting values (physical units, :data:`PARAM_NAMES` order)."""
    return np.array([TABLE[n][0] for n in PARAM_NAMES], float)


def bounds_z() -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds on the fitted scale."""
    lo = to_z(np.array([TABLE[n][1] for n in PARAM_NAMES]))
    hi = to_z(np.array([TABLE[n][2] for n in PARAM_NAMES]))
    return lo, hi


def prior_centre_z() -> np.ndarray:
    """Centres of the priors on the fitted scale (the literature values)."""
    return to_z(start_theta())
