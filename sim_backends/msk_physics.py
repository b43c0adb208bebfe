"""What turns MuJoCo's elbow model into an FES experiment: electrodes, fixture, fatigue.

The musculoskeletal participant (:mod:`nmsid.sim_backends.msk_participant`) drives the six
muscles of MyoSuite's ``myoelbow_1dof6muscles`` (TRIlong, TRIlat, TRImed: extensors;
BIClong, BICshort, BRA: flexors) through two surface electrodes. Every setting here is a
plain frozen dataclass, validated on construction, drawn per participant by
:mod:`nmsid.sim_backends.msk_population`; the defaults are the population's centre.

* :class:`Recruitment`: the fraction of one muscle's fibres an electrode recruits, a
  sigmoid in current with a threshold and a saturation (Crago, Peckham & Thrope 1980,
  "Modulation of muscle force by recruitment during intramuscular stimulation", IEEE TBME
  27:679; Durfee & MacLean 1989, "Methods for estimating isometric recruitment curves of
  electrically stimulated muscle", IEEE TBME 36:654). Surface electrodes reach only the
  superficial part of a muscle group at tolerable currents, so ``max_activation`` is
  well below 1.
* :class:`MuscleDrive`: one muscle's activation command: its own electrode's recruitment
  plus spill-over of the other electrode's field (current spread to neighbouring muscles,
  which needs more current and recruits less: e.g. Mesin et al. 2010; Merletti et al.
  1992 on the crosstalk of surface stimulation).
* :class:`FixtureMount`: the isometric fixture. The forearm is strapped to a cuff on the
  force sensor; strap, soft tissue and sensor form a compliant mount, i.e. a rotational
  spring-damper about the fixture angle. With the forearm's inertia it gives the roughly
  second-order endpoint dynamics the paper measures; the forearm rests on the fixture, so
  gravity does not load the sensor (the model runs without gravity).
* :class:`CoactivationStiffness`: the short-range stiffness of active muscle, which a
  Hill-type model lacks: joint stiffness and damping that grow with co-activation (Hogan
  1984, "Adaptive control of mechanical impedance by coactivation of antagonist muscles",
  IEEE TAC 29:681; Kearney & Hunter 1990, elbow stiffness rising linearly with torque),
  per muscle ``gamma F / L0`` times its squared moment arm (Cui et al. 2008, "Modeling
  short-range stiffness of feline lower hindlimb muscles", J Biomech 41:1945: gamma about
  23). It makes the endpoint's wn and zeta depend on sE, as the paper measures.
* :class:`MuscleFatigue`: a fatigue state per muscle scaling its maximal active force
  (first-order fatigue / recovery driven by activation, as in Riener, Quintern & Schmidt
  1996, "Biomechanical model of the human knee evaluated by neuromuscular stimulation",
  J Biomech 29:1157; Ding et al. 2000's force-fatigue model has the same structure). Off by
  default (``tau_fatigue_s = inf``): the fast clock runs the 45 trials without the
  paper's 60 s rests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nmsid.sim_backends.errors import SimConfigError

EXTENSORS = ("TRIlong", "TRIlat", "TRImed")
FLEXORS = ("BIClong", "BICshort", "BRA")
MUSCLES = EXTENSORS + FLEXORS
"""Actuator order of ``myoelbow_1dof6muscles``."""

MUSCLE_GROUPS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "elbow": (EXTENSORS, FLEXORS),
    # MyoLeg (Rajagopal et al. 2016), right leg: quadriceps vs hamstrings
    "knee": (("recfem_r", "vasint_r", "vaslat_r", "vasmed_r"),
             ("bflh_r", "bfsh_r", "semimem_r", "semiten_r")),
    # triceps surae vs tibialis anterior, with the toe extensors beside it under the
    # dorsiflexor electrode (neighbours it spills onto)
    "ankle": (("gasmed_r", "gaslat_r", "soleus_r"), ("tibant_r", "edl_r", "ehl_r")),
}
"""Per musculoskeletal joint: its extensor-channel and flexor-channel muscles, in the
model's actuator order (extensors first)."""

_EXTENSOR_SET = frozenset(m for ext, _ in MUSCLE_GROUPS.values() for m in ext)
_ALL_MUSCLES = frozenset(m for ext, flex in MUSCLE_GROUPS.values() for m in ext + flex)


def joint_muscles(joint: str) -> tuple[str, ...]:
    """The actuator order of the musculoskeletal model of ``joint`` (extensors, flexors)."""
    try:
        ext, flex = MUSCLE_GROUPS[joint]
    except KeyError:
        raise SimConfigError(f"no musculoskeletal model of joint {joint!r}; valid: "
                             f"{', '.join(MUSCLE_GROUPS)}") from None
    return ext + flex


def _finite(owner: str, name: str, value, lo: float = -math.inf, hi: float = math.inf,
            *, lo_open: bool = False) -> float:
    v = float(value)
    ok = math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi
    if not ok:
        rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise SimConfigError(f"{owner} {name} must be a finite number in {rng}, got {value!r}")
    return v


@dataclass(frozen=True)
class Recruitment:
    """Fraction of a muscle's fibres recruited by one electrode, as a function of current.

    ``r(I) = max_activation * (S(I) - S(I_th)) / (1 - S(I_th))`` for ``I > I_th``, else 0,
    with ``S(I) = 1 / (1 + exp(-(I - I50) / width))``: zero up to the threshold, a
    sigmoid rise (Crago et al. 1980; Durfee & MacLean 1989), saturating at
    ``max_activation``.

    Parameters
    ----------
    threshold_mA : float
        No fibre is recruited at or below this current (motor threshold; surface
        stimulation of the arm: about 1-4 mA at 250-300 us pulses).
    I50_mA : float
        Current of the sigmoid's midpoint (steepest recruitment).
    width_mA : float
        Sigmoid scale: 10 % -> 90 % of the sigmoid over ``4.4 width_mA``.
    max_activation : float
        Fraction of the muscle's fibres the electrode can reach, in (0, 1].
    """

    threshold_mA: float = 2.0
    I50_mA: float = 8.0
    width_mA: float = 1.5
    max_activation: float = 0.1

    def __post_init__(self):
        _finite("recruitment", "threshold_mA", self.threshold_mA, 0.0, 100.0)
        _finite("recruitment", "I50_mA", self.I50_mA, self.threshold_mA, 100.0, lo_open=True)
        _finite("recruitment", "width_mA", self.width_mA, 0.0, 100.0, lo_open=True)
        _finite("recruitment", "max_activation", self.max_activation, 0.0, 1.0)

    def __call__(self, current_mA) -> np.ndarray:
        """Recruited fraction (0 .. ``max_activation``) for currents in mA."""
        I = np.asarray(current_mA, dtype=float)
        s_th = 1.0 / (1.0 + math.exp(-(self.threshold_mA - self.I50_mA) / self.width_mA))
        s = 1.0 / (1.0 + np.exp(-(I - self.I50_mA) / self.width_mA))
        return self.max_activation * np.clip((s - s_th) / (1.0 - s_th), 0.0, 1.0)


@dataclass(frozen=True)
class MuscleDrive:
    """How the two electrodes drive one muscle.

    Parameters
    ----------
    muscle : str
        Actuator name in the MuJoCo model (one of :data:`MUSCLES`).
    own : Recruitment
        Recruitment by the electrode over this muscle's group (extensor electrode for
        the triceps heads, flexor electrode for biceps and brachialis).
    spill : Recruitment
        Recruitment by the *other* electrode (current spread); ``max_activation = 0``
        for none.
    """

    muscle: str
    own: Recruitment
    spill: Recruitment = Recruitment(threshold_mA=6.0, I50_mA=14.0, width_mA=2.0,
                                     max_activation=0.0)

    def __post_init__(self):
        if self.muscle not in _ALL_MUSCLES:
            raise SimConfigError(f"muscle {self.muscle!r} is not in the elbow or leg models; "
                                 f"valid: {', '.join(sorted(_ALL_MUSCLES))}")

    @property
    def is_extensor(self) -> bool:
        return self.muscle in _EXTENSOR_SET

    def command(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> np.ndarray:
        """The muscle's excitation (MuJoCo ``ctrl``, 0..1) for delivered currents."""
        own, other = (I_ext_mA, I_flex_mA) if self.is_extensor else (I_flex_mA, I_ext_mA)
        u = self.own(own)
        if self.spill.max_activation > 0:
            u = u + self.spill(other)
        return np.minimum(u, 1.0)


def default_drives() -> tuple[MuscleDrive, ...]:
    """The population's centre: triceps heads recruited 2.0-2.5 mA upwards (lateral head
    first, it lies under the electrode), biceps heads and brachialis 1.5-2.5 mA upwards
    (brachialis lies deep: higher threshold, smaller reach); 5 % spill-over above 6 mA."""
    def r(th, i50, w, a):
        return Recruitment(th, i50, w, a)
    spill = Recruitment(6.0, 13.0, 2.0, 0.05 * 0.12)
    return (MuscleDrive("TRIlong", r(2.5, 9.0, 1.6, 0.10), spill),
            MuscleDrive("TRIlat", r(2.0, 8.0, 1.5, 0.14), spill),
            MuscleDrive("TRImed", r(2.5, 9.5, 1.8, 0.08), spill),
            MuscleDrive("BIClong", r(1.5, 7.5, 1.4, 0.12), spill),
            MuscleDrive("BICshort", r(1.5, 7.5, 1.4, 0.12), spill),
            MuscleDrive("BRA", r(2.5, 9.0, 1.8, 0.06), spill))


@dataclass(frozen=True)
class FixtureMount:
    """The isometric fixture: forearm strapped to a cuff on the force sensor.

    The strap, the soft tissue under it and the sensor (stiff: a six-axis cell deflects a
    few um) act as a rotational spring-damper about ``angle_deg``; with the forearm's
    moment of inertia about the elbow (from the MuJoCo model, about 0.07 kg m^2) it has
    natural frequency ``wn_rad_s`` and damping ratio ``zeta``. Co-activated muscles add
    their own stiffness (force-length) and damping (force-velocity), so the endpoint
    dynamics stiffen with co-contraction, as the paper finds (wn, zeta 10-40 rad/s,
    0.3-1). The sensor reads the spring's force plus ``sensed_damping_fraction`` of the
    damping (the strap's viscosity is in series with the sensor; the joint's own tissue
    damping is not), at ``lever_m`` from the elbow.

    Parameters
    ----------
    angle_deg : float
        Elbow flexion held by the fixture (0 = straight; the paper's fixture: 90 deg).
    wn_rad_s, zeta : float
        Natural frequency and damping ratio of the relaxed forearm on the mount.
    sensed_damping_fraction : float
        Part of the mount's damping transmitted through the sensor, in [0, 1].
    lever_m : float or None
        Distance elbow -> cuff along the forearm (the force is torque / lever); None for a
        dynamometer that measures the joint torque itself (knee, ankle: N m).
    added_inertia_kgm2 : float
        Inertia the fixture adds about the joint (a dynamometer's arm or footplate moving
        with the limb); the elbow's cuff: 0.

    The same mount holds a leg on a dynamometer: the shank (knee) or the foot (ankle)
    strapped to the dynamometer's arm or footplate, whose compliance (strap, soft tissue,
    arm) is the spring-damper and whose torque is read directly (``lever_m = None``);
    ``angle_deg`` is then the knee's flexion or the ankle's dorsiflexion (MyoLeg's
    ``knee_angle_r`` / ``ankle_angle_r``, checked against the model's range).
    """

    angle_deg: float = 90.0
    wn_rad_s: float = 18.0
    zeta: float = 0.45
    sensed_damping_fraction: float = 0.2
    lever_m: float | None = 0.22
    added_inertia_kgm2: float = 0.0

    def __post_init__(self):
        _finite("mount", "angle_deg", self.angle_deg, -60.0, 150.0)
        _finite("mount", "wn_rad_s", self.wn_rad_s, 1.0, 200.0)
        _finite("mount", "zeta", self.zeta, 0.05, 5.0)
        _finite("mount", "sensed_damping_fraction", self.sensed_damping_fraction, 0.0, 1.0)
        if self.lever_m is not None:
            _finite("mount", "lever_m", self.lever_m, 0.05, 0.4)
        _finite("mount", "added_inertia_kgm2", self.added_inertia_kgm2, 0.0, 5.0)

    def stiffness_damping(self, inertia_kgm2: float) -> tuple[float, float]:
        """(K in N m/rad, B in N m s/rad) for the forearm's inertia about the elbow."""
        K = inertia_kgm2 * self.wn_rad_s ** 2
        return K, 2.0 * self.zeta * math.sqrt(K * inertia_kgm2)


@dataclass(frozen=True)
class CoactivationStiffness:
    """Short-range stiffness of the active muscles about the elbow.

    Joint stiffness ``K_j = sum_m gamma r_m^2 F0_m e_m / L0_m`` (``r_m`` the muscle's
    moment arm at the fixture angle, ``L0_m`` its optimal fibre length, both from the
    MuJoCo model, ``e_m`` its excitation) and damping ``damping_s K_j``, acting about the
    rest angle through a first-order lag of the activation time constant. The sensor does
    not see it directly: it shunts part of the muscle torque and stiffens the dynamics.

    Limitation: the spring acts about the rest angle at any deflection, whereas real
    short-range stiffness yields beyond a few per cent of stretch and does not resist a
    muscle's own steady shortening; so it also shunts part of the *static* force (with
    ``gamma = 8`` about 10-25 % at Fmax). Cui et al.'s 23 would cap the static force of a
    single muscle near 10 N on this mount, hence the default of 8.

    Parameters
    ----------
    gamma : float
        Dimensionless short-range stiffness (stiffness x L0 / force; about 23 in Cui et
        al. 2008, 8 here, see above; 0 switches it off).
    damping_s : float
        Damping per unit stiffness, s (muscle viscosity: 0.01-0.03 s at the elbow, e.g.
        Kearney & Hunter 1990's B/K).
    """

    gamma: float = 8.0
    damping_s: float = 0.02

    def __post_init__(self):
        _finite("coactivation stiffness", "gamma", self.gamma, 0.0, 200.0)
        _finite("coactivation stiffness", "damping_s", self.damping_s, 0.0, 1.0)


@dataclass(frozen=True)
class MuscleFatigue:
    """Fatigue of the stimulated fibres: a state ``f`` in [``min_fraction``, 1] per muscle
    scales its maximal active force.

    ``df/dt = -(f - f_min) a / tau_fatigue + (1 - f) (1 - a) / tau_recovery``, ``a`` the
    muscle's recruited fraction relative to its electrode's reach (Riener et al. 1996;
    Ding et al. 2000). It is integrated exactly over segments of
    ``segment_s`` with ``a`` held at the segment's mean.

    Parameters
    ----------
    tau_fatigue_s : float
        Time constant of force loss under full recruitment (FES of the arm: 30-120 s;
        ``inf``: no fatigue, the default).
    tau_recovery_s : float
        Time constant of recovery without stimulation (minutes).
    min_fraction : float
        Force left when fully fatigued.
    segment_s : float
        Update interval of the fatigue state.
    """

    tau_fatigue_s: float = math.inf
    tau_recovery_s: float = 120.0
    min_fraction: float = 0.4
    segment_s: float = 0.25

    def __post_init__(self):
        if not (self.tau_fatigue_s > 0):
            raise SimConfigError(f"fatigue tau_fatigue_s must be > 0 (inf: none), got "
                                 f"{self.tau_fatigue_s!r}")
        _finite("fatigue", "tau_recovery_s", self.tau_recovery_s, 0.0, 1e6, lo_open=True)
        _finite("fatigue", "min_fraction", self.min_fraction, 0.0, 1.0)
        _finite("fatigue", "segment_s", self.segment_s, 1e-3, 10.0)

    @property
    def enabled(self) -> bool:
        return math.isfinite(self.tau_fatigue_s)

    def step(self, f: np.ndarray, a: np.ndarray, dt_s: float) -> np.ndarray:
        """The state after ``dt_s`` with relative activation ``a`` (per muscle) held.

        Exact solution of the linear ODE: rate ``k = a / tau_f + (1 - a) / tau_r``,
        equilibrium ``(f_min a / tau_f + (1 - a) / tau_r) / k``.
        """
        a = np.clip(a, 0.0, 1.0)
        kf = a / self.tau_fatigue_s if self.enabled else np.zeros_like(a)
        kr = (1.0 - a) / self.tau_recovery_s
        k = kf + kr
        with np.errstate(invalid="ignore", divide="ignore"):
            f_eq = np.where(k > 0, (self.min_fraction * kf + kr) / np.where(k > 0, k, 1), f)
        return f_eq + (f - f_eq) * np.exp(-k * dt_s)
