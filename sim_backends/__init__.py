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
    "make_sim_rig": "sim_backends.rig", "SimRig": "sim_backends.rig",
    "VirtualParticipant": "sim_backends.participant",
    "default_participant": "sim_backends.participant",
    "TrueParameters": "sim_backends.participant",
    "ReferenceCalibration": "sim_backends.participant",
    "participant_from_twin": "sim_backends.twin",
    "make_population": "sim_backends.population",
    "MskParticipant": "sim_backends.msk_participant",
    "default_msk_participant": "sim_backends.msk_participant",
    "make_msk_population": "sim_backends.msk_population",
    "FaultScript": "sim_backends.faults", "Fault": "sim_backends.faults",
    "FaultKind": "sim_backends.faults",
    "FastClock": "sim_backends.clocks", "SimRealClock": "sim_backends.clocks",
    "SensorModel": "sim_backends.sensor",
    "ParameterCurve": "sim_backends.curves", "CurveModel": "sim_backends.curves",
    "DeadTime": "sim_backends.effects", "ActivationDynamics": "sim_backends.effects",
    "Fatigue": "sim_backends.effects", "RecruitmentNonlinearity": "sim_backends.effects",
    "BaselineDrift": "sim_backends.effects",
    "FlexorExtensorAsymmetry": "sim_backends.effects",
    "EFFECT_NAMES": "sim_backends.effects",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sim_backends' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
