"""A musculoskeletal virtual participant: MyoSuite's elbow model in MuJoCo under FES.

Same role and interface as :class:`nmsid.sim_backends.participant.VirtualParticipant` (``code``,
``seed``, ``sensor``, ``true_parameters``, ``effect_truth``, ``ramp_calibration``; the
rig gets its simulator from :meth:`MskParticipant.make_simulator`), but the physics is
not the paper's model:

* six Hill-type muscles of ``myoelbow_1dof6muscles`` (``myo_sim``) with MuJoCo's own
  activation dynamics, force-length-velocity and passive force, one MuJoCo step per
  2 kHz sample;
* two electrodes recruiting the triceps heads / biceps heads and brachialis along
  sigmoid recruitment curves with thresholds, saturation and spill-over
  (:mod:`nmsid.sim_backends.msk_physics`);
* short-range stiffness growing with co-activation (absent from Hill-type models);
* the forearm on a compliant isometric mount (strap, tissue, sensor), gravity carried by
  the fixture, the template participant's sensor chain;
* optional muscle fatigue.

Its ground truth is the best second-order description of its noise-free response per sE
(:mod:`nmsid.sim_backends.msk_truth`): :meth:`MskParticipant.second_order_truth` gives Kp, wn,
zeta and the fit % a second-order model reaches; :meth:`true_parameters` the first three
as a :class:`~nmsid.sim_backends.participant.TrueParameters`, as the template participant does.

Examples
--------
>>> p = default_msk_participant(seed=3)
>>> rig = make_sim_rig(p)                            # doctest: +SKIP
>>> p.ramp_calibration()                             # doctest: +SKIP
>>> p.second_order_truth(0.65).fit_pct               # doctest: +SKIP
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from nmsid.protocols.calibration import (
    Muscle,
    make_calibration,
    ramp_currents_mA,
    require_thresholds,
    settled_mean_N,
    step_envelopes,
)
from nmsid.protocols.config import CalibrationConfig, ProtocolConfig
from nmsid.protocols.joints import JOINTS
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_physics import (
    CoactivationStiffness,
    FixtureMount,
    MuscleDrive,
    MuscleFatigue,
    default_drives,
    joint_muscles,
)
from nmsid.sim_backends.msk_simulation import MskSimulator
from nmsid.sim_backends.msk_truth import SecondOrderTruth, second_order_truth
from nmsid.sim_backends.participant import TrueParameters
from nmsid.sim_backends.sensor import SensorModel

MODEL_KIND = "musculoskeletal"
"""The value of ``[participant] model`` / ``--participant-model`` that selects it."""


@dataclass(frozen=True)
class MskParticipant:
    """A musculoskeletal participant (see the module docstring).

    Parameters
    ----------
    code : str
        Participant code, ``[A-Za-z0-9_-]{1,64}``.
    drives : tuple of MuscleDrive
        One per muscle, in the model's actuator order (:data:`~sim_backends.msk_physics.
        MUSCLES`): recruitment by its own electrode and spill-over from the other.
    mount : FixtureMount
        The isometric fixture.
    tau_act_s, tau_deact_s : float
        Activation / deactivation time constants of MuJoCo's muscle activation dynamics
        (its own default, 10 / 40 ms, is for voluntary excitation; the force response to
        electrical stimulation is slower, the twitch contraction time of human elbow
        muscles being 40-80 ms: Zajac 1989, "Muscle and tendon", Crit Rev Biomed Eng
        17:359; Riener & Fuhr 1998, "Patient-driven control of FES-supported standing
        up", IEEE TRE 6:113).
    stiffening : CoactivationStiffness
        Short-range stiffness of the active muscles (``gamma = 0``: the bare Hill model).
    fatigue : MuscleFatigue
        Off by default.
    sensor : SensorModel
        The measurement chain (the template participant's).
    seed : int
        Seeds the sensor noise.
    joint : str
        ``elbow`` (MyoSuite's elbow, force at the cuff in N) or ``knee`` / ``ankle``
        (MyoLeg on a dynamometer, torque in N m; :mod:`nmsid.sim_backends.msk_leg`).
    """

    code: str = "MSK01"
    drives: tuple = field(default_factory=default_drives)
    mount: FixtureMount = field(default_factory=FixtureMount)
    tau_act_s: float = 0.03
    tau_deact_s: float = 0.06
    stiffening: CoactivationStiffness = field(default_factory=CoactivationStiffness)
    fatigue: MuscleFatigue = field(default_factory=MuscleFatigue)
    sensor: SensorModel = field(default_factory=SensorModel)
    seed: int = 0
    joint: str = "elbow"

    model_kind = MODEL_KIND

    def __post_init__(self):
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", str(self.code)):
            raise SimConfigError(f"participant code {self.code!r} must match "
                                 "[A-Za-z0-9_-]{1,64}")
        drives = tuple(self.drives)
        muscles = joint_muscles(self.joint)
        if tuple(getattr(d, "muscle", None) for d in drives) != muscles or not all(
                isinstance(d, MuscleDrive) for d in drives):
            raise SimConfigError(f"drives must be one MuscleDrive per muscle in the order "
                                 f"{', '.join(muscles)}")
        object.__setattr__(self, "drives", drives)
        if not (0.001 <= self.tau_act_s <= 0.5 and 0.001 <= self.tau_deact_s <= 0.5):
            raise SimConfigError(f"tau_act_s / tau_deact_s must lie in [0.001, 0.5] s, got "
                                 f"{self.tau_act_s!r} / {self.tau_deact_s!r}")

    # -- the rig -------------------------------------------------------------------------
    def make_simulator(self, fs_Hz: float) -> MskSimulator:
        """The stateful simulator :class:`nmsid.sim_backends.world.SimWorld` drives."""
        return MskSimulator(self, fs_Hz)

    # -- what a calibration ramp finds ---------------------------------------------------
    def ramp_calibration(self, cfg: CalibrationConfig | None = None, fs_Hz: float = 2000.0):
        """What the engine's ramp finds on this participant without sensor noise.

        The engine's sequence is simulated: extensor then flexor, each a rest, a baseline
        (the tare) and ``step_mA`` steps held ``hold_s``, the settled part averaged,
        until Fmin and Fmax are both reached.

        Returns
        -------
        protocols.session_file.Calibration

        Raises
        ------
        protocols.errors.CalibrationError
            If a ramp never reaches Fmin / Fmax below its ceiling.
        """
        if cfg is None:     # the joint's thresholds (in N m at a knee or an ankle)
            j = JOINTS[self.joint]
            cfg = CalibrationConfig(Fmin_N=j.Fmin, Fmax_N=j.Fmax, force_ceiling_N=j.ceiling)
        return _ramp_calibration(self, cfg, float(fs_Hz))

    # -- ground truth --------------------------------------------------------------------
    def second_order_truth(self, sE: float, calibration=None,
                           protocol: ProtocolConfig | None = None) -> SecondOrderTruth:
        """The best second-order description at ``sE`` (Kp, wn, zeta, fit %).

        ``calibration``: the currents the session used (default: what the ramp finds,
        :meth:`ramp_calibration`).
        """
        cal = calibration if calibration is not None else self.ramp_calibration()
        return second_order_truth(self, sE, cal, protocol)

    def true_parameters(self, sE: float, calibration=None,
                        protocol: ProtocolConfig | None = None) -> TrueParameters:
        """``(Kp, wn_rad_s, zeta)`` of :meth:`second_order_truth`."""
        t = self.second_order_truth(sE, calibration, protocol)
        return TrueParameters(t.Kp, t.wn_rad_s, t.zeta)

    def effect_truth(self) -> list[dict]:
        """No twin-file effects: its departures from second order are physics, not add-ons
        (their size is :attr:`SecondOrderTruth.fit_pct`)."""
        return []

    def trial_variant(self, gain: float = 1.0, speed: float = 1.0,
                      damping: float = 1.0) -> MskParticipant:
        """The same participant on another trial: the physiology that varies between
        repeats, scaled by factors near 1.

        ``gain`` scales every electrode's reach (``max_activation``, own and spill-over:
        electrode-skin contact and the fibres under it change between trials, which moves
        the force per unit rE, Kp); ``speed`` divides the activation and deactivation time
        constants and multiplies the mount's natural frequency (muscle temperature, strap
        tension: wn); ``damping`` scales the mount's damping ratio (zeta). The factors
        act on physics, not on a second-order template, so the scatter they give in Kp, wn
        and zeta is the model's own mapping of them.

        Raises
        ------
        SimConfigError
            If a factor is not in (0.2, 5) or a scaled value leaves its valid range.
        """
        for name, v in (("gain", gain), ("speed", speed), ("damping", damping)):
            if not (0.2 < float(v) < 5.0):
                raise SimConfigError(f"trial_variant {name} factor {v!r}: give a factor in "
                                     "(0.2, 5), near 1")
        drives = tuple(replace(
            d, own=replace(d.own, max_activation=min(1.0, d.own.max_activation * gain)),
            spill=replace(d.spill, max_activation=min(1.0, d.spill.max_activation * gain)))
            for d in self.drives)
        mount = replace(self.mount, wn_rad_s=self.mount.wn_rad_s * speed,
                        zeta=self.mount.zeta * damping)
        return replace(self, drives=drives, mount=mount, tau_act_s=self.tau_act_s / speed,
                       tau_deact_s=self.tau_deact_s / speed)


@lru_cache(maxsize=64)
def _ramp_calibration(p: MskParticipant, c: CalibrationConfig, fs_Hz: float):
    sim = MskSimulator(replace(p, sensor=SensorModel.ideal()), fs_Hz)
    found = {}
    ramps = {}
    for muscle in (Muscle.EXTENSOR, Muscle.FLEXOR):
        sim.advance_quiet(int(round(c.rest_s * fs_Hz)))
        n_base = max(1, int(round(c.baseline_s * fs_Hz)))
        z = np.zeros(n_base)
        base = settled_mean_N(sim.simulate(z, z).true_force_N, c.settle_fraction)
        cur, frc = [], []
        for I in ramp_currents_mA(c, muscle):
            ext, flex = step_envelopes(c, muscle, float(I), fs_Hz)
            f = settled_mean_N(sim.simulate(ext, flex).true_force_N, c.settle_fraction) - base
            cur.append(float(I))
            frc.append(f)
            if abs(f) >= c.force_ceiling_N or (muscle.sign * f >= c.Fmax_N):
                break
        found[muscle] = require_thresholds(cur, frc, muscle, c)
        ramps[f"{muscle.prefix}_currents_mA"] = np.asarray(cur)
        ramps[f"{muscle.prefix}_force_N"] = np.asarray(frc)
    return make_calibration(found[Muscle.EXTENSOR], found[Muscle.FLEXOR], c, ramps)


def default_msk_participant(seed: int = 0, **changes) -> MskParticipant:
    """The population's centre (:mod:`nmsid.sim_backends.msk_population`) with ``seed`` for its
    sensor noise; ``changes`` replace fields."""
    return replace(MskParticipant(seed=int(seed)), **changes)
