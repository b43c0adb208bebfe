"""MyoLeg participants: the knee and the ankle of MuJoCo's MyoLeg on a dynamometer under FES.

The musculoskeletal participant of the elbow (:mod:`nmsid.sim_backends.msk_participant`)
with the leg's model (:mod:`nmsid.sim_backends.msk_myoleg`): the same
:class:`~nmsid.sim_backends.msk_participant.MskParticipant` (``joint="knee"`` or
``"ankle"``), the same simulator, electrodes, co-activation stiffness, fatigue and truth,
so the rig, the engine, rollback / replay and every fault injection run on it unchanged.
What differs is data:

* **Knee** (quadriceps on the extensor channel, hamstrings on the flexor channel): knee at
  ``KNEE_ANGLE_DEG`` of flexion, hip at 85 deg (seated on the dynamometer). The
  quadriceps electrode recruits the superficial vastus lateralis and medialis and rectus
  femoris first, the deep vastus intermedius least; the hamstrings electrode the long
  head of biceps femoris and semitendinosus first, semimembranosus and the short head
  less. Each electrode spills over onto the other group (current spread through the
  thigh) at higher currents.
* **Ankle** (triceps surae on the extensor channel, tibialis anterior on the flexor
  channel): ankle neutral (0 deg), knee extended. The calf electrode recruits the
  gastrocnemius heads and the soleus beneath them; the dorsiflexor electrode the
  tibialis anterior and, beside it, extensor digitorum longus and extensor hallucis
  longus (neighbours it reaches); each spills onto the other group.
* **Measurement**: the dynamometer's torque about the joint, N m, extension (knee) /
  plantarflexion (ankle) positive, tared at rest; the arm and strap compliance as the
  mount (``FixtureMount(lever_m=None)``); the sensor chain of the joint's template
  participant (:func:`nmsid.sim_backends.joint_participants.joint_sensor`).

Ranges drawn per participant (:func:`make_leg_population`), from the FES and
dynamometry literature: recruitment thresholds, midpoints, widths and reaches so that the
ramp finds Imin near 2-5 mA and Imax near 6-11 mA on the simulated stimulator (its
16 mA range; real thigh electrodes need more current, which only rescales the axis:
Maffiuletti 2010, Eur J Appl Physiol 110:223), reaches sized so that Fmax (50 N m at
the knee, 20 N m at the ankle: ``protocols/joints.py``) lies well inside them;
spill-over 2-10 % of the other group's own reach, beginning 3-7 mA above its threshold;
activation time constants 60-90 ms (knee) / 80-110 ms (ankle), deactivation 1.5-2.5 times
that (leg muscles' electrically evoked twitches peak after 70-130 ms, the triceps
surae's latest: Vandervoort & McComas 1986, J Appl Physiol 61:361); the dynamometer arm
(0.1-0.2 kg m^2) or footplate (0.04-0.08 kg m^2) moving with the limb, and the arm,
strap and soft tissue as a mount of 40-65 rad/s (knee, about 1-3 kN m/rad) / 65-100
rad/s (ankle, about 0.3-0.9 kN m/rad) with damping ratio 0.4-0.8 (dynamometer and
strap compliance lets a joint rotate by degrees at a maximal contraction: Arampatzis
et al. 2004, J Biomech 37:1251); posture within +/-5 deg of the nominal.

The best second-order description of the centre participants
(:meth:`~nmsid.sim_backends.msk_participant.MskParticipant.second_order_truth`): knee Kp
18.7 -> 88.8 N m per unit rE from sE 0.3 to 1.0, wn 18.4-18.8 rad/s, zeta 1.21-1.27,
fit 91-92 %; ankle Kp 8.2 -> 35.3 N m, wn 18.3-20.4 rad/s, zeta 1.47-1.73, fit 93-95 %
(over-damped: activation's lag in series with the stiff dynamometer).

Examples
--------
>>> p = default_leg_participant("knee", seed=2)
>>> p.joint, p.code, p.mount.lever_m
('knee', 'MK01', None)
>>> [q.code for q in make_leg_population(2, seed=1, joint="ankle")]
['A01', 'A02']
>>> p.ramp_calibration().Fmax_N                                # doctest: +SKIP
50.0
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.joint_participants import joint_sensor
from nmsid.sim_backends.msk_participant import MskParticipant
from nmsid.sim_backends.msk_physics import (
    MUSCLE_GROUPS,
    CoactivationStiffness,
    FixtureMount,
    MuscleDrive,
    MuscleFatigue,
    Recruitment,
    joint_muscles,
)
from nmsid.sim_backends.population import draw_sensor

LEG_JOINTS = ("knee", "ankle")

KNEE_ANGLE_DEG = 60.0
"""Knee flexion the dynamometer holds (docs/joints.md: ~60 deg)."""
ANKLE_ANGLE_DEG = 0.0
"""Ankle angle the footplate holds (neutral)."""

# (threshold_mA, I50_mA, width_mA, reach) of each muscle's own electrode, nominal
_NOMINAL: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "knee": {"recfem_r": (2.5, 7.5, 1.6, 0.30), "vasint_r": (3.0, 8.5, 1.8, 0.12),
             "vaslat_r": (2.0, 7.0, 1.5, 0.30), "vasmed_r": (2.5, 7.5, 1.6, 0.25),
             "bflh_r": (1.5, 6.5, 1.4, 0.50), "bfsh_r": (2.5, 8.0, 1.8, 0.25),
             "semimem_r": (2.0, 7.5, 1.6, 0.35), "semiten_r": (1.5, 6.5, 1.4, 0.50)},
    "ankle": {"gasmed_r": (2.0, 7.0, 1.5, 0.15), "gaslat_r": (2.0, 7.0, 1.5, 0.15),
              "soleus_r": (2.5, 8.0, 1.8, 0.12), "tibant_r": (1.5, 6.5, 1.4, 0.70),
              "edl_r": (2.0, 7.5, 1.6, 0.50), "ehl_r": (2.5, 8.0, 1.8, 0.40)},
}
"""The population's centre: each muscle's recruitment by its own electrode."""

_MOUNT = {"knee": FixtureMount(angle_deg=KNEE_ANGLE_DEG, wn_rad_s=50.0, zeta=0.6,
                               sensed_damping_fraction=0.2, lever_m=None,
                               added_inertia_kgm2=0.15),
          "ankle": FixtureMount(angle_deg=ANKLE_ANGLE_DEG, wn_rad_s=80.0, zeta=0.6,
                                sensed_damping_fraction=0.2, lever_m=None,
                                added_inertia_kgm2=0.06)}
_TAU_S = {"knee": (0.075, 0.15), "ankle": (0.095, 0.19)}
"""Activation / deactivation time constants of the population's centre."""
_TAU_ACT_RANGE = {"knee": (0.06, 0.09), "ankle": (0.08, 0.11)}
_MOUNT_WN = {"knee": (40.0, 65.0), "ankle": (65.0, 100.0)}
_ADDED_INERTIA = {"knee": (0.1, 0.2), "ankle": (0.04, 0.08)}
"""Dynamometer arm / footplate inertia about the joint, kg m^2."""


def _check(joint: str) -> str:
    if joint not in LEG_JOINTS:
        raise SimConfigError(f"MyoLeg participant joint {joint!r}: valid: "
                             f"{', '.join(LEG_JOINTS)}")
    return joint


def _spill(reach: float, other_threshold_mA: float) -> Recruitment:
    th = other_threshold_mA + 5.0
    return Recruitment(th, th + 6.0, 2.0, 0.05 * reach)


def leg_drives(joint: str) -> tuple[MuscleDrive, ...]:
    """The population's centre: own recruitment (``_NOMINAL``), 5 % spill-over from the
    other electrode beginning 5 mA above that group's threshold."""
    ext, flex = MUSCLE_GROUPS[_check(joint)]
    nominal = _NOMINAL[joint]
    th = {m: nominal[m][0] for m in ext + flex}
    g_th = {"ext": min(th[m] for m in ext), "flex": min(th[m] for m in flex)}
    return tuple(MuscleDrive(m, Recruitment(*nominal[m]),
                             _spill(nominal[m][3], g_th["flex" if m in ext else "ext"]))
                 for m in joint_muscles(joint))


def default_leg_participant(joint: str, seed: int = 0, **changes) -> MskParticipant:
    """The MyoLeg participant at the population's centre for ``joint`` (``knee`` or
    ``ankle``), ``seed`` for its sensor noise; ``changes`` replace fields."""
    _check(joint)
    tau_a, tau_d = _TAU_S[joint]
    p = MskParticipant(code="MK01" if joint == "knee" else "MA01", drives=leg_drives(joint),
                       mount=_MOUNT[joint], tau_act_s=tau_a, tau_deact_s=tau_d,
                       sensor=joint_sensor(joint), seed=int(seed), joint=joint)
    return replace(p, **changes)


def make_leg_participant(rng: np.random.Generator, joint: str, code: str, seed: int, *,
                         fatigue: bool = False) -> MskParticipant:
    """One random MyoLeg participant of ``joint`` (ranges: the module docstring)."""
    ext, flex = MUSCLE_GROUPS[_check(joint)]
    nominal = _NOMINAL[joint]
    group_th = {"ext": rng.uniform(1.0, 3.0), "flex": rng.uniform(1.0, 3.0)}
    spill_frac = rng.uniform(0.02, 0.10)
    spill_above = rng.uniform(3.0, 7.0)
    drives = []
    for m in joint_muscles(joint):
        own_g, other_g = ("ext", "flex") if m in ext else ("flex", "ext")
        reach = nominal[m][3] * rng.uniform(0.75, 1.3)
        th = group_th[own_g] + rng.uniform(0.0, 1.0)
        own = Recruitment(th, th + rng.uniform(4.5, 7.0), rng.uniform(1.0, 2.2), reach)
        s_th = group_th[other_g] + spill_above
        spill = Recruitment(s_th, s_th + rng.uniform(5.0, 8.0), rng.uniform(1.5, 2.5),
                            spill_frac * reach)
        drives.append(MuscleDrive(m, own, spill))
    nominal_angle = KNEE_ANGLE_DEG if joint == "knee" else ANKLE_ANGLE_DEG
    mount = FixtureMount(angle_deg=nominal_angle + rng.uniform(-5.0, 5.0),
                         wn_rad_s=rng.uniform(*_MOUNT_WN[joint]), zeta=rng.uniform(0.4, 0.8),
                         sensed_damping_fraction=rng.uniform(0.1, 0.4), lever_m=None,
                         added_inertia_kgm2=rng.uniform(*_ADDED_INERTIA[joint]))
    tau_act = rng.uniform(*_TAU_ACT_RANGE[joint])
    tau_deact = tau_act * rng.uniform(1.5, 2.5)
    fat_draw = (rng.uniform(60.0, 240.0), rng.uniform(60.0, 300.0), rng.uniform(0.3, 0.6))
    fat = MuscleFatigue(*fat_draw) if fatigue else MuscleFatigue()
    sensor = joint_sensor(joint, draw_sensor(rng))
    stiff = CoactivationStiffness(rng.uniform(4.0, 12.0), rng.uniform(0.01, 0.03))
    return MskParticipant(code=code, drives=tuple(drives), mount=mount, tau_act_s=tau_act,
                          tau_deact_s=tau_deact, stiffening=stiff, fatigue=fat,
                          sensor=sensor, seed=seed, joint=joint)


def make_leg_population(n: int, seed: int = 0, joint: str = "knee", *,
                        fatigue: bool = False) -> list[MskParticipant]:
    """``n`` MyoLeg participants of ``joint``, reproducible from ``seed``; codes ``K01``,
    ... (knee) or ``A01``, ... (ankle). Participant i depends only on (seed, joint, i)."""
    _check(joint)
    if int(n) != n or n < 0:
        raise SimConfigError(f"n must be an integer >= 0, got {n!r}")
    out = []
    for i in range(int(n)):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, i, 6162,
                                     LEG_JOINTS.index(joint)])
        p_seed = int(rng.integers(0, 2 ** 31 - 1))
        out.append(make_leg_participant(rng, joint, f"{joint[0].upper()}{i + 1:02d}",
                                        p_seed, fatigue=fatigue))
    return out
