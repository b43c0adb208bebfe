"""A seeded population of virtual participants that differ the way the paper's ten do.

The paper (Hori et al.) found, over sE in 0.3-1.0: Kp increasing for everyone, best fitted
by linear (4 of 10), exponential (5) or concave quadratic (1) models; wn and zeta with an
extremum for some participants and monotonic (extremum outside the range) for others,
with linear, exponential or quadratic best fits. The generator draws:

* curve families dealt out in the paper's proportions (every ten consecutive participants:
  Kp 4 linear / 5 exponential / 1 concave quadratic; wn 2 / 3 / 5 quadratic; zeta 4 / 4 /
  2 quadratic), in a seeded order;
* Kp increasing, Kp(0.3) in 2-4 N and Kp(1.0) in 6-14 N per unit rE;
* wn and zeta: a quadratic has its extremum (mostly a peak, the paper's convex-upward
  shape; sometimes a trough) inside the range 3 times in 5, else outside it (it then
  looks monotonic); linear and exponential ones are monotonic; wn in 10-50 rad/s, zeta in
  0.3-1.0 over the range, and ``zeta wn >= 8 1/s`` so that a 1 s calibration step
  settles;
* calibration currents on the 0.5 mA grid (Imin 1-4 mA, span 4.5-9 mA);
* sensor noise 0.02-0.06 N RMS, offset, slow drift and mains pick-up of different sizes.

These are the elbow's ranges; ``make_population(n, seed, joint="knee")`` draws the same
families with the knee's or the ankle's ranges and units
(:data:`nmsid.sim_backends.joint_participants.TEMPLATES`, ``docs/joints.md``).

Examples
--------
>>> pop = make_population(3, seed=1)
>>> [p.code for p in pop]
['S01', 'S02', 'S03']
>>> make_population(3, seed=1)[2] == pop[2]
True
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from nmsid.protocols.joints import JOINTS
from nmsid.sim_backends.curves import CurveModel, ParameterCurve
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.joint_participants import joint_sensor, template_for
from nmsid.sim_backends.participant import ReferenceCalibration, VirtualParticipant
from nmsid.sim_backends.sensor import SensorModel

SE_LO, SE_HI = 0.30, 1.00
_GRID = np.linspace(SE_LO, SE_HI, 15)


# The best-fitting families of the paper's ten participants (Tables 2, 5, 8); a population
# deals them out in a seeded order, so any ten consecutive participants have these counts.
KP_FAMILIES = ("quadratic",) + ("linear",) * 4 + ("exponential",) * 5
WN_FAMILIES = ("linear",) * 2 + ("exponential",) * 3 + ("quadratic",) * 5
ZETA_FAMILIES = ("quadratic",) * 2 + ("exponential",) * 4 + ("linear",) * 4


def _kp_curve(rng: np.random.Generator, family: str,
              lo: tuple[float, float] = (2.0, 4.0), hi: tuple[float, float] = (6.0, 14.0)
              ) -> ParameterCurve:
    k_lo = rng.uniform(*lo)
    k_hi = rng.uniform(*hi)
    if family == "exponential":
        b = math.log(k_hi / k_lo) / (SE_HI - SE_LO)
        return ParameterCurve(CurveModel.EXPONENTIAL, (k_hi * math.exp(-b * SE_HI), b))
    if family == "linear":
        b = (k_hi - k_lo) / (SE_HI - SE_LO)
        return ParameterCurve(CurveModel.LINEAR, (k_lo - b * SE_LO, b))
    # concave quadratic through both ends, bulging above the chord at mid-range
    mid = 0.5 * (SE_LO + SE_HI)
    bulge = rng.uniform(0.05, 0.2) * (k_hi - k_lo)
    A = np.array([[1, SE_LO, SE_LO ** 2], [1, SE_HI, SE_HI ** 2], [1, mid, mid ** 2]])
    y = np.array([k_lo, k_hi, 0.5 * (k_lo + k_hi) + bulge])
    return ParameterCurve(CurveModel.QUADRATIC, tuple(np.linalg.solve(A, y)))


def _trend_curve(rng: np.random.Generator, lo: float, hi: float, family: str
                 ) -> ParameterCurve:
    """A curve within [lo, hi] over the sE range.

    quadratic: an extremum (a peak 4 times in 5, else a trough) at sE_x, inside the range
    (0.4-0.9) 3 times in 5, else outside it (0.0-0.2 or 1.1-1.4: the curve looks
    monotonic); linear / exponential: a monotonic trend.
    """
    span = hi - lo
    if family == "quadratic":
        if rng.uniform() < 0.6:
            s_x = rng.uniform(0.4, 0.9)
        else:
            s_x = rng.uniform(0.0, 0.2) if rng.uniform() < 0.5 else rng.uniform(1.1, 1.4)
        far = max((SE_LO - s_x) ** 2, (SE_HI - s_x) ** 2)
        if rng.uniform() < 0.8:     # peak: x_x - c (s - s_x)^2
            x_x = rng.uniform(lo + 0.45 * span, hi - 0.05 * span)
            c = -rng.uniform(0.3, 1.0) * (x_x - (lo + 0.05 * span)) / far
        else:                       # trough: x_x + c (s - s_x)^2
            x_x = rng.uniform(lo + 0.05 * span, hi - 0.45 * span)
            c = rng.uniform(0.3, 1.0) * ((hi - 0.05 * span) - x_x) / far
        # x_x + c (s - s_x)^2 = a + b s + c s^2
        return ParameterCurve(CurveModel.QUADRATIC, (x_x + c * s_x ** 2, -2 * c * s_x, c))
    v_lo = rng.uniform(lo + 0.05 * span, hi - 0.05 * span)
    v_hi = rng.uniform(lo + 0.05 * span, hi - 0.05 * span)
    if family == "linear":
        b = (v_hi - v_lo) / (SE_HI - SE_LO)
        return ParameterCurve(CurveModel.LINEAR, (v_lo - b * SE_LO, b))
    b = math.log(v_hi / v_lo) / (SE_HI - SE_LO)
    return ParameterCurve(CurveModel.EXPONENTIAL, (v_hi * math.exp(-b * SE_HI), b))


def _calibration(rng: np.random.Generator) -> ReferenceCalibration:
    def pair():
        imin = 0.5 * rng.integers(2, 9)          # 1.0 .. 4.0 mA
        span = 0.5 * rng.integers(9, 19)         # 4.5 .. 9.0 mA
        return float(imin), float(imin + span)
    (emin, emax), (fmin, fmax) = pair(), pair()
    return ReferenceCalibration(emin, emax, fmin, fmax)


def _sensor(rng: np.random.Generator) -> SensorModel:
    return SensorModel(noise_N=rng.uniform(0.02, 0.06), offset_N=rng.uniform(-0.5, 0.5),
                       drift_N_per_s=rng.uniform(-5e-4, 5e-4),
                       mains_N=rng.uniform(0.005, 0.05),
                       mains_phase_rad=rng.uniform(0, 2 * np.pi),
                       cross_noise_N=rng.uniform(0.01, 0.03))


draw_sensor = _sensor
"""Draw a sensor chain (noise 0.02-0.06 N RMS, offset, drift, mains): shared with the
musculoskeletal population (:mod:`nmsid.sim_backends.msk_population`)."""


def make_participant(rng: np.random.Generator, code: str, seed: int,
                     families: tuple[str, str, str] = ("exponential", "quadratic",
                                                       "quadratic"),
                     joint: str = "elbow") -> VirtualParticipant:
    """One random participant with curve families (Kp, wn, zeta), resampled until its
    curves meet the population's ranges (the joint's:
    :data:`nmsid.sim_backends.joint_participants.TEMPLATES`)."""
    t = template_for(joint)
    j = JOINTS[t.joint]
    (w_lo, w_hi), (z_lo, z_hi) = t.wn_range, t.zeta_range
    for _ in range(500):
        Kp = _kp_curve(rng, families[0], t.Kp_lo, t.Kp_hi)
        wn = _trend_curve(rng, w_lo, w_hi, families[1])
        zeta = _trend_curve(rng, z_lo, z_hi, families[2])
        kp, w, z = Kp(_GRID), wn(_GRID), zeta(_GRID)
        if not (np.all(np.diff(kp) > 0) and w.min() >= w_lo and w.max() <= w_hi
                and z.min() >= z_lo and z.max() <= z_hi
                and (w * z).min() >= t.min_decay_1_s):
            continue
        cal = _calibration(rng)
        if j.name != "elbow":
            cal = replace(cal, Fmin_N=j.Fmin, Fmax_N=j.Fmax)
        return VirtualParticipant(code=code, Kp=Kp, wn_rad_s=wn, zeta=zeta,
                                  calibration=cal, sE_range=(SE_LO, SE_HI),
                                  sensor=joint_sensor(j, _sensor(rng)), seed=seed)
    raise SimConfigError("could not draw a participant within the population's ranges")


def make_population(n: int, seed: int = 0, joint: str = "elbow") -> list[VirtualParticipant]:
    """``n`` participants of ``joint`` (its gains, unit and dynamics), reproducible from
    ``seed``; codes ``S01``, ``S02``, ...

    Participant i depends only on (seed, i), so ``make_population(5, s)[:3] ==
    make_population(3, s)``.
    """
    if int(n) != n or n < 0:
        raise SimConfigError(f"n must be an integer >= 0, got {n!r}")
    deal = np.random.default_rng([int(seed) & 0xFFFFFFFF, 777])
    orders = [deal.permutation(10) for _ in range(3)]
    out = []
    for i in range(int(n)):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, i, 4242])
        p_seed = int(rng.integers(0, 2 ** 31 - 1))
        kp, wn, zeta = (table[order[i % 10]] for table, order in
                        zip((KP_FAMILIES, WN_FAMILIES, ZETA_FAMILIES), orders, strict=True))
        families = (kp, wn, zeta)
        out.append(make_participant(rng, f"S{i + 1:02d}", p_seed, families, joint))
    return out
