"""A seeded population of musculoskeletal participants (MuJoCo elbow under FES).

Each participant is the same MyoSuite elbow (``myoelbow_1dof6muscles``) with its own
electrodes, fixture, muscle time constants, fatigue and sensor chain, drawn from ranges
taken from the FES literature (each range is documented on its dataclass in
:mod:`nmsid.sim_backends.msk_physics` / :mod:`nmsid.sim_backends.msk_participant`):

* recruitment per muscle (Crago et al. 1980; Durfee & MacLean 1989): motor threshold
  1-3 mA, sigmoid midpoint 4.5-7.5 mA above it, width 1-2.2 mA, reach (fraction of the
  muscle's fibres the surface electrode recruits at saturation) 8-16 % for the superficial
  triceps and biceps heads, 3-8 % for the deep brachialis; so that a 0.5 mA ramp finds
  Imin near 2-5 mA and Imax near 5-10 mA, as in the paper;
* spill-over of each electrode onto the other group: 2-10 % of that muscle's own reach,
  beginning 3-7 mA above the electrode's own threshold (current spread needs more current);
* mount: relaxed-forearm natural frequency 12-30 rad/s, damping ratio 0.3-0.8, 10-40 %
  of the damping sensed (strap in series with the sensor), cuff 18-26 cm from the elbow,
  elbow at 80-100 deg;
* activation / deactivation time constants 20-40 ms / 1.5-2.5 times that (electrically
  elicited twitches are slower than voluntary activation: Zajac 1989);
* co-activation stiffness (short-range stiffness) ``gamma`` 4-12, damping 0.01-0.03 s per
  unit stiffness (:class:`~nmsid.sim_backends.msk_physics.CoactivationStiffness`);
* fatigue only with ``fatigue=True``: time constant 60-240 s under full recruitment,
  recovery 60-300 s, 30-60 % of force left when exhausted (Riener et al. 1996; Ding et al.
  2000); without it the population's truth is the unfatigued participant;
* sensor noise, offset, drift and mains as the template population
  (:func:`nmsid.sim_backends.population.draw_sensor`).

Examples
--------
>>> pop = make_msk_population(3, seed=1)
>>> [p.code for p in pop]
['M01', 'M02', 'M03']
>>> make_msk_population(3, seed=1)[2] == pop[2]
True
"""

from __future__ import annotations

import numpy as np

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_participant import MskParticipant
from nmsid.sim_backends.msk_physics import (
    EXTENSORS,
    MUSCLES,
    CoactivationStiffness,
    FixtureMount,
    MuscleDrive,
    MuscleFatigue,
    Recruitment,
)
from nmsid.sim_backends.population import draw_sensor

REACH = {"TRIlong": (0.08, 0.14), "TRIlat": (0.10, 0.16), "TRImed": (0.06, 0.12),
         "BIClong": (0.08, 0.16), "BICshort": (0.08, 0.16), "BRA": (0.03, 0.08)}
"""Range of each muscle's reach (fraction of fibres recruited at saturation)."""


def _drives(rng: np.random.Generator) -> tuple[MuscleDrive, ...]:
    reach = {m: rng.uniform(*REACH[m]) for m in MUSCLES}
    group_th = {"ext": rng.uniform(1.0, 3.0), "flex": rng.uniform(1.0, 3.0)}
    spill_frac = rng.uniform(0.02, 0.10)
    spill_above = rng.uniform(3.0, 7.0)
    out = []
    for m in MUSCLES:
        own_g, other_g = ("ext", "flex") if m in EXTENSORS else ("flex", "ext")
        th = group_th[own_g] + rng.uniform(0.0, 1.0)     # heads differ a little
        own = Recruitment(th, th + rng.uniform(4.5, 7.5), rng.uniform(1.0, 2.2), reach[m])
        s_th = group_th[other_g] + spill_above
        spill = Recruitment(s_th, s_th + rng.uniform(5.0, 8.0), rng.uniform(1.5, 2.5),
                            spill_frac * reach[m])
        out.append(MuscleDrive(m, own, spill))
    return tuple(out)


def make_msk_participant(rng: np.random.Generator, code: str, seed: int, *,
                         fatigue: bool = False) -> MskParticipant:
    """One random musculoskeletal participant (ranges: the module docstring)."""
    drives = _drives(rng)
    mount = FixtureMount(angle_deg=rng.uniform(80.0, 100.0), wn_rad_s=rng.uniform(12.0, 30.0),
                         zeta=rng.uniform(0.3, 0.8),
                         sensed_damping_fraction=rng.uniform(0.1, 0.4),
                         lever_m=rng.uniform(0.18, 0.26))
    tau_act = rng.uniform(0.02, 0.04)
    tau_deact = tau_act * rng.uniform(1.5, 2.5)
    fat_draw = (rng.uniform(60.0, 240.0), rng.uniform(60.0, 300.0), rng.uniform(0.3, 0.6))
    fat = MuscleFatigue(*fat_draw) if fatigue else MuscleFatigue()
    sensor = draw_sensor(rng)
    stiff = CoactivationStiffness(rng.uniform(4.0, 12.0), rng.uniform(0.01, 0.03))
    return MskParticipant(code=code, drives=drives, mount=mount, tau_act_s=tau_act,
                          tau_deact_s=tau_deact, stiffening=stiff, fatigue=fat,
                          sensor=sensor, seed=seed)


def make_msk_population(n: int, seed: int = 0, *, fatigue: bool = False
                        ) -> list[MskParticipant]:
    """``n`` musculoskeletal participants, reproducible from ``seed``; codes ``M01``, ...

    Participant i depends only on (seed, i) (and ``fatigue``, which only switches the
    drawn fatigue on), so ``make_msk_population(5, s)[:3] == make_msk_population(3, s)``.
    """
    if int(n) != n or n < 0:
        raise SimConfigError(f"n must be an integer >= 0, got {n!r}")
    out = []
    for i in range(int(n)):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, i, 6161])
        p_seed = int(rng.integers(0, 2 ** 31 - 1))
        out.append(make_msk_participant(rng, f"M{i + 1:02d}", p_seed, fatigue=fatigue))
    return out
