"""MuJoCo's MyoLeg reduced to one isometric joint: the right knee or the right ankle.

MyoLeg (``myo_sim``'s lower-limb model, ``models/leg/assets/myolegs_*.xml``, after
Rajagopal et al. 2016, "Full-body musculoskeletal model for muscle-driven simulation of
human gait", IEEE TBME 63:2068) has 80 muscles and 28 degrees of freedom; a step costs
about 190 us, forty times the elbow's. An isometric session moves one joint by a fraction
of a degree, so :func:`leg_spec` keeps what that joint needs and welds the rest in the
posture of the protocol (``protocols/joints.py``):

* the right leg only (the left leg's bodies, muscles, tendons and knee couplings go);
* the hip welded at ``HIP_FLEXION_DEG`` (seated on the dynamometer: the biarticular
  rectus femoris and hamstrings at their seated lengths); the pelvis is fixed already;
* **knee**: the knee's own degrees of freedom stay (``knee_angle_r`` with the tibia's
  and the patella's coupled translations and rotations, held to it by the model's
  polynomial equality constraints); the ankle, subtalar and toe joints are welded at
  neutral; muscles: the quadriceps (rectus femoris, vastus intermedius, lateralis,
  medialis) and the hamstrings (biceps femoris long and short heads, semimembranosus,
  semitendinosus);
* **ankle**: the knee welded extended (0 deg), subtalar and toes welded, ``ankle_angle_r``
  free; muscles: the triceps surae (gastrocnemius medialis and lateralis, soleus), the
  tibialis anterior and its neighbours under the same electrode (extensor digitorum and
  hallucis longus);
* sensors and contacts removed (contacts are switched off by the simulator anyway).

The reduced models cost about 12 us (knee) and 8 us (ankle) a step on this machine
(the elbow's: 5 us). :func:`load_leg_model` returns the spec for
:func:`nmsid.sim_backends.msk_model.load_model` to add the co-activation stiffness
actuator and compile; mujoco and myo_sim are the optional ``mujoco`` extra, imported by
the caller.
"""

from __future__ import annotations

import math

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_physics import joint_muscles

HIP_FLEXION_DEG = 85.0
"""Hip flexion of the seated knee posture (docs/joints.md: hip ~85 deg)."""

MODEL_JOINT = {"knee": "knee_angle_r", "ankle": "ankle_angle_r"}
"""The MyoLeg joint each participant's dynamometer holds and measures. Signs: knee
flexion and ankle dorsiflexion are positive in MyoLeg, so the joint's positive torque
(knee extension, plantarflexion) is ``K (q_rest - q)``, as at the elbow."""

_HIP = ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r")
_FOOT = ("subtalar_angle_r", "mtp_angle_r")
_KNEE = ("knee_angle_translation2_r", "knee_angle_translation1_r", "knee_angle_r",
         "knee_angle_rotation2_r", "knee_angle_rotation3_r",
         "knee_angle_beta_translation2_r", "knee_angle_beta_translation1_r",
         "knee_angle_beta_rotation1_r")
WELDED = {"knee": _HIP + ("ankle_angle_r",) + _FOOT, "ankle": _HIP + _KNEE + _FOOT}
"""Joints welded in place per participant joint."""


def leg_spec(mujoco, myo_sim, joint: str):
    """The editable MyoLeg spec reduced to ``joint`` (module docstring).

    Parameters
    ----------
    mujoco, myo_sim : module
        The imported packages (the caller owns the lazy import).
    joint : str
        ``knee`` or ``ankle``.
    """
    if joint not in MODEL_JOINT:
        raise SimConfigError(f"MyoLeg participant joint {joint!r}: valid: "
                             f"{', '.join(MODEL_JOINT)}")
    keep = set(joint_muscles(joint))
    welded = set(WELDED[joint])
    spec = myo_sim.FRAGMENT_SPEC_BUILDERS["myolegs"]()   # the bare legs, pelvis fixed
    for a in list(spec.actuators):
        if a.name not in keep:
            spec.delete(a)
    tendons = {a.target for a in spec.actuators}
    for t in list(spec.tendons):
        if t.name not in tendons:
            spec.delete(t)
    for e in list(spec.equalities):
        if e.name.endswith("_l") or e.name1 in welded or e.name2 in welded:
            spec.delete(e)
    for s in list(spec.sensors):
        spec.delete(s)
    spec.delete(spec.body("femur_l"))
    for j in list(spec.joints):
        if j.name in welded:
            spec.delete(j)
    if joint == "knee":          # seated: the femur welded at the hip's flexion
        half = math.radians(HIP_FLEXION_DEG) / 2.0
        spec.body("femur_r").quat = [math.cos(half), 0.0, 0.0, math.sin(half)]
    return spec
