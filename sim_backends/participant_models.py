"""The simulated participant a configuration names (``[participant] model``).

``template``: the paper's second-order model (:func:`sim_backends.participant.
default_participant`); ``musculoskeletal``: MyoSuite's MuJoCo elbow under FES
(:func:`nmsid.sim_backends.msk_participant.default_msk_participant`), or at the knee and
the ankle MuJoCo's MyoLeg on a dynamometer
(:func:`nmsid.sim_backends.msk_leg.default_leg_participant`); both need the ``mujoco``
extra. Both take the session's simulation seed for their sensor noise. A lab's own model:
``package.module:factory`` (:mod:`nmsid.sim_backends.plugin`).
"""

from __future__ import annotations

from nmsid.protocols.config import PARTICIPANT_MODELS
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.joint_participants import template_participant
from nmsid.sim_backends.msk_leg import LEG_JOINTS, default_leg_participant
from nmsid.sim_backends.msk_participant import default_msk_participant
from nmsid.sim_backends.plugin import plugin_participant


def participant_for_model(model: str, seed: int = 0, fs_Hz: float = 2000.0,
                          joint: str = "elbow"):
    """The default participant of that model with ``seed`` at ``joint`` (a plug-in is
    checked at the session's ``fs_Hz``).

    Raises
    ------
    SimConfigError
        If ``model`` is not one of :data:`nmsid.protocols.config.PARTICIPANT_MODELS`, or
        has no participant of that joint (the musculoskeletal one is an elbow).
    """
    if model == "template":
        return template_participant(joint, seed=int(seed))
    if model == "musculoskeletal":
        if joint in LEG_JOINTS:          # MuJoCo's MyoLeg on a dynamometer
            return default_leg_participant(joint, seed=int(seed))
        if joint != "elbow":
            raise SimConfigError(f"participant model 'musculoskeletal' has the elbow, the knee "
                                 f"and the ankle; for joint {joint!r} use model 'template' "
                                 "(docs/joints.md)")
        return default_msk_participant(seed=int(seed))
    if ":" in str(model):   # a lab's plug-in, package.module:factory
        return plugin_participant(model, seed=int(seed), fs_Hz=float(fs_Hz))
    raise SimConfigError(f"participant model {model!r} is unknown; valid: "
                         + ", ".join(PARTICIPANT_MODELS))
