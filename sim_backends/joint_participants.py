"""Template participants per joint: the paper's model with each joint's typical numbers.

The template participant (:mod:`nmsid.sim_backends.participant`) is the paper's model, so
it holds for any agonist/antagonist pair; what differs between joints is the scale of the
gain (N at the elbow's strap, N m at a knee or ankle dynamometer), the speed of the
muscles' isometric response and the calibration thresholds. :data:`TEMPLATES` holds one
:class:`JointTemplate` per shipped joint (``protocols/joints.py``); a joint without one (a
lab's own entry) gets the elbow's dynamics with its gain and noise scaled to the joint's
calibration range (:func:`template_for`).

Where the numbers come from (typical values, to give the simulator realistic shapes; they
are not measurements of anyone):

* **Gains.** Kp rises with sE as the paper found at the elbow (exponential, Kp(1) / Kp(0.3)
  about 3.8). The knee's Kp(1.0) of 90 N m per unit rE and the ankle's 36 N m are a
  fraction of the voluntary maxima (knee extension ~150-300 N m, plantarflexion
  ~100-200 N m: Harbo et al. 2012, Eur J Appl Physiol 112:267-275), in line with evoked
  torques being a fraction of the maximum (Maffiuletti 2010, Eur J Appl Physiol
  110:223-234).
* **Dynamics.** The wn of a second-order isometric response is of the order of the inverse
  of the twitch's time to peak. Quadriceps twitches peak after roughly 70-100 ms, so wn
  11-15 rad/s; triceps surae (soleus-dominated) twitches after roughly 100-130 ms, against
  80-90 ms for the dorsiflexors (Vandervoort & McComas 1986, J Appl Physiol 61:361-367),
  so wn 9-11 rad/s. Both are well damped (zeta 0.75-1.0); the elbow's template keeps the
  paper's faster, less damped shape (wn 10-50 rad/s, zeta 0.3-1.0).
* **Noise.** The elbow sensor chain's noise, offset, drift and mains scaled by the
  joint's Fmax / the elbow's Fmax (a dynamometer's torque channel in N m, same relative
  resolution); range the joint's ``sensor_range``.

Examples
--------
>>> p = template_participant("knee", seed=3)
>>> round(p.true_parameters(1.0).Kp, 1), p.calibration.Fmax_N
(90.3, 50.0)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from nmsid.protocols.joints import JOINTS, Joint
from nmsid.sim_backends.curves import CurveModel, ParameterCurve
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.participant import (
    ReferenceCalibration,
    VirtualParticipant,
    default_participant,
)
from nmsid.sim_backends.sensor import SensorModel

__all__ = ["JointTemplate", "TEMPLATES", "template_for", "template_participant"]


def _peak(x_peak: float, s_peak: float, x_end: float, s_end: float) -> ParameterCurve:
    """A quadratic with its extremum ``x_peak`` at ``s_peak`` through ``(s_end, x_end)``."""
    c = (x_end - x_peak) / (s_end - s_peak) ** 2
    return ParameterCurve(CurveModel.QUADRATIC,
                          (x_peak + c * s_peak ** 2, -2.0 * c * s_peak, c))


def _line(x_lo: float, x_hi: float, s_lo: float = 0.3, s_hi: float = 1.0) -> ParameterCurve:
    b = (x_hi - x_lo) / (s_hi - s_lo)
    return ParameterCurve(CurveModel.LINEAR, (x_lo - b * s_lo, b))


@dataclass(frozen=True)
class JointTemplate:
    """A joint's template participant and its population's ranges.

    ``Kp`` / ``wn_rad_s`` / ``zeta``: the nominal curves (Kp in the joint's unit per unit
    rE). Population (:func:`nmsid.sim_backends.population.make_population`): Kp(0.3) in
    ``Kp_lo``, Kp(1.0) in ``Kp_hi``; wn in ``wn_range``, zeta in ``zeta_range``, and
    ``zeta wn >= min_decay_1_s`` so that a 1 s calibration step settles.
    """

    joint: str
    Kp: ParameterCurve
    wn_rad_s: ParameterCurve
    zeta: ParameterCurve
    Kp_lo: tuple[float, float]
    Kp_hi: tuple[float, float]
    wn_range: tuple[float, float]
    zeta_range: tuple[float, float]
    min_decay_1_s: float = 8.0

    @property
    def scale(self) -> float:
        """The joint's Fmax over the elbow's: the gain and noise scale of its unit."""
        return JOINTS[self.joint].Fmax / JOINTS["elbow"].Fmax


_ELBOW = default_participant()

TEMPLATES: dict[str, JointTemplate] = {
    "elbow": JointTemplate("elbow", _ELBOW.Kp, _ELBOW.wn_rad_s, _ELBOW.zeta,
                           Kp_lo=(2.0, 4.0), Kp_hi=(6.0, 14.0), wn_range=(10.0, 50.0),
                           zeta_range=(0.3, 1.0)),
    "knee": JointTemplate("knee", ParameterCurve(CurveModel.EXPONENTIAL, (13.5, 1.9)),
                          _peak(15.0, 0.7, 12.0, 0.3), _line(0.75, 0.95),
                          Kp_lo=(18.0, 32.0), Kp_hi=(60.0, 120.0), wn_range=(11.0, 16.0),
                          zeta_range=(0.72, 1.0)),
    "ankle": JointTemplate("ankle", ParameterCurve(CurveModel.EXPONENTIAL, (5.4, 1.9)),
                           _peak(11.0, 0.7, 9.5, 0.3), _line(0.88, 1.0),
                           Kp_lo=(7.0, 13.0), Kp_hi=(25.0, 50.0), wn_range=(9.0, 12.0),
                           zeta_range=(0.82, 1.0)),
}
"""The shipped joints' templates (module docstring: where the numbers come from)."""


def template_for(joint: Joint | str) -> JointTemplate:
    """The joint's template; a joint without one: the elbow's dynamics, gains scaled by
    the joint's Fmax over the elbow's.

    Raises
    ------
    SimConfigError
        If ``joint`` names no registered joint.
    """
    name = joint.name if isinstance(joint, Joint) else str(joint)
    if name not in JOINTS:
        raise SimConfigError(f"joint {name!r} is unknown; valid: {', '.join(JOINTS)}")
    if name in TEMPLATES:
        return TEMPLATES[name]
    k = JOINTS[name].Fmax / JOINTS["elbow"].Fmax
    e = TEMPLATES["elbow"]
    return replace(e, joint=name,
                   Kp=ParameterCurve(e.Kp.model, (e.Kp.coefficients[0] * k,)
                                     + tuple(e.Kp.coefficients[1:]))
                   if e.Kp.model is CurveModel.EXPONENTIAL else e.Kp,
                   Kp_lo=(e.Kp_lo[0] * k, e.Kp_lo[1] * k), Kp_hi=(e.Kp_hi[0] * k,
                                                                  e.Kp_hi[1] * k))


def joint_sensor(joint: Joint | str, base: SensorModel | None = None) -> SensorModel:
    """``base`` (default the elbow's chain) in the joint's unit: noise, offset, drift and
    mains scaled by the joint's Fmax over the elbow's, range the joint's sensor range, the
    A/D's full scale at that range."""
    j = JOINTS[joint.name if isinstance(joint, Joint) else str(joint)]
    b = base or SensorModel()
    if j.name == "elbow":
        return b
    k = j.Fmax / JOINTS["elbow"].Fmax
    return replace(b, noise_N=b.noise_N * k, offset_N=b.offset_N * k,
                   drift_N_per_s=b.drift_N_per_s * k, mains_N=b.mains_N * k,
                   cross_noise_N=b.cross_noise_N * k, range_N=j.sensor_range,
                   volts_per_N=b.adc_range_V / j.sensor_range)


def template_participant(joint: Joint | str = "elbow", seed: int = 0,
                         **changes) -> VirtualParticipant:
    """The template participant of ``joint`` (the elbow's: :func:`default_participant`):
    its curves, the calibration currents of the elbow's template with the joint's Fmin /
    Fmax, its sensor chain (:func:`joint_sensor`)."""
    t = template_for(joint)
    j = JOINTS[t.joint]
    if j.name == "elbow":
        return default_participant(seed=seed, **changes)
    c = _ELBOW.calibration
    cal = ReferenceCalibration(c.Iemin_mA, c.Iemax_mA, c.Ifmin_mA, c.Ifmax_mA,
                               Fmin_N=j.Fmin, Fmax_N=j.Fmax, step_mA=c.step_mA)
    base = VirtualParticipant(code="SIM01", Kp=t.Kp, wn_rad_s=t.wn_rad_s, zeta=t.zeta,
                              calibration=cal, sensor=joint_sensor(j), seed=seed)
    return replace(base, **changes)
