"""The simulated rig: a virtual participant (two muscles, second-order dynamics whose
parameters depend on sE, sensor noise, optional unmodelled effects) behind the same device
interfaces as the hardware, with a real-time and an as-fast-as-possible clock and
scriptable fault injection.

Public API (imported lazily, so ``import sim_backends`` stays light)::

    make_sim_rig, SimRig                       # the rig (drivers.interfaces.RigDevices)
    MskParticipant, default_msk_participant    # MuJoCo elbow (optional 'mujoco' extra)
    make_msk_population
    VirtualParticipant, default_participant    # the participant; .true_parameters(sE, cal)
    TrueParameters, ReferenceCalibration
    participant_from_twin, make_population
    FaultScript, Fault, FaultKind
    FastClock, SimRealClock
    effects: DeadTime, ActivationDynamics, Fatigue, RecruitmentNonlinearity,
             BaselineDrift, FlexorExtensorAsymmetry, EFFECT_NAMES
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "make_sim_rig": "nmsid.sim_backends.rig", "SimRig": "nmsid.sim_backends.rig",
    "VirtualParticipant": "nmsid.sim_backends.participant",
    "default_participant": "nmsid.sim_backends.participant",
    "TrueParameters": "nmsid.sim_backends.participant",
    "ReferenceCalibration": "nmsid.sim_backends.participant",
    "participant_from_twin": "nmsid.sim_backends.twin",
    "make_population": "nmsid.sim_backends.population",
    "MskParticipant": "nmsid.sim_backends.msk_participant",
    "default_msk_participant": "nmsid.sim_backends.msk_participant",
    "make_msk_population": "nmsid.sim_backends.msk_population",
    "FaultScript": "nmsid.sim_backends.faults", "Fault": "nmsid.sim_backends.faults",
    "FaultKind": "nmsid.sim_backends.faults",
    "FastClock": "nmsid.sim_backends.clocks", "SimRealClock": "nmsid.sim_backends.clocks",
    "SensorModel": "nmsid.sim_backends.sensor",
    "ParameterCurve": "nmsid.sim_backends.curves", "CurveModel": "nmsid.sim_backends.curves",
    "DeadTime": "nmsid.sim_backends.effects", "ActivationDynamics": "nmsid.sim_backends.effects",
    "Fatigue": "nmsid.sim_backends.effects",
    "RecruitmentNonlinearity": "nmsid.sim_backends.effects",
    "BaselineDrift": "nmsid.sim_backends.effects",
    "FlexorExtensorAsymmetry": "nmsid.sim_backends.effects",
    "EFFECT_NAMES": "nmsid.sim_backends.effects",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sim_backends' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
