"""MyoSuite's elbow and MyoLeg's knee / ankle in MuJoCo, configured as FES participants on
an isometric rig.

:func:`load_model` compiles ``myoelbow_1dof6muscles.xml`` from the ``myo_sim`` package
(or MyoLeg reduced to the knee or the ankle, :mod:`nmsid.sim_backends.msk_myoleg`) once
per process (mujoco and myo_sim are the optional ``mujoco`` extra, imported
here only); :func:`configure` returns a private copy set up for one participant:

* timestep ``1 / fs_Hz`` (one MuJoCo step per acquisition sample, 0.5 ms at 2 kHz);
* gravity off (the forearm rests on the fixture: gravity loads the support, not the
  sensor) and contacts off (no contact pairs matter on an isometric rig; this also makes
  a step about 25 % cheaper);
* the fixture as the elbow joint's spring (``stiffness``; ``springref`` set so that the
  relaxed forearm, with the muscles' passive force, rests at the fixture angle: the
  strap's preload) and damping (:class:`~nmsid.sim_backends.msk_physics.FixtureMount`);
* each muscle's activation and deactivation time constants (MuJoCo's muscle activation
  dynamics, ``dynprm[0:2]``); force-length-velocity and passive force are the model's own;
* on a leg, the dynamometer arm's compliance as the same spring-damper on the knee's or
  the ankle's joint, whose torque (N m) is read instead of a cuff force;
* one extra actuator on the measured joint (added with ``mujoco.MjSpec`` when the model is
  loaded, index 6): the co-activation stiffness (:class:`~sim_backends.msk_physics.
  CoactivationStiffness`), an affine-gain actuator whose control is the stiffness in
  N m/rad, so that ``force = ctrl ((q_rest - q) - damping_s qdot)``, behind a first-order
  filter with the activation time constant.
"""

from __future__ import annotations

import copy
import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmsid.errors import MissingDependency
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_myoleg import MODEL_JOINT as MYOLEG_JOINT
from nmsid.sim_backends.msk_myoleg import leg_spec
from nmsid.sim_backends.msk_physics import (
    CoactivationStiffness,
    FixtureMount,
    joint_muscles,
)

MODEL_NAME = "myoelbow"
STIFFNESS_ACTUATOR = "coactivation_stiffness"
"""``myo_sim`` registry name of ``models/legacy/elbow/myoelbow_1dof6muscles.xml``."""

REST_SETTLE_S = 3.0
"""Simulated time without stimulation from which the rest state is taken."""

_lock = threading.Lock()
_base: dict[str, Any] = {}


class MujocoUnavailable(MissingDependency):
    """mujoco or myo_sim is not installed (the optional ``mujoco`` extra)."""


def _import_mujoco():
    # lazy: mujoco and myo_sim are an optional extra; the rest of nmsid works without them
    try:
        import mujoco
        import myo_sim
        from mujoco import rollout
    except ImportError as exc:
        raise MujocoUnavailable(
            f"the musculoskeletal participant needs the 'mujoco' extra ({exc}); install it "
            "with: pip install -e '.[mujoco]'") from None
    return mujoco, myo_sim, rollout


def model_path() -> str:
    """Path of ``myoelbow_1dof6muscles.xml`` inside the installed ``myo_sim``."""
    _, myo_sim, _ = _import_mujoco()
    return str(myo_sim.get_xml_path(MODEL_NAME))


def load_elbow_model():
    """The compiled elbow model, shared (read-only) by every :func:`configure` call."""
    return load_model("elbow")


def load_model(joint: str = "elbow"):
    """The compiled model of ``joint`` (the elbow; MyoLeg's knee or ankle,
    :mod:`nmsid.sim_backends.msk_myoleg`) with the co-activation stiffness actuator
    appended, shared (read-only) by every :func:`configure` call."""
    with _lock:
        if joint not in _base:
            mujoco, myo_sim, _ = _import_mujoco()
            if joint == "elbow":
                spec = mujoco.MjSpec.from_file(model_path())
                target = "r_elbow_flex"
            else:
                spec = leg_spec(mujoco, myo_sim, joint)
                target = MYOLEG_JOINT[joint]
            a = spec.add_actuator()
            a.name = STIFFNESS_ACTUATOR
            a.target = target
            a.trntype = mujoco.mjtTrn.mjTRN_JOINT
            a.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            a.gaintype = mujoco.mjtGain.mjGAIN_AFFINE
            a.biastype = mujoco.mjtBias.mjBIAS_NONE
            a.ctrllimited = 0
            a.gear[0] = 1.0
            m = spec.compile()
            names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i)
                          for i in range(m.nu))
            want = joint_muscles(joint)
            if sorted(names[:-1]) != sorted(want) or names[-1] != STIFFNESS_ACTUATOR or (
                    joint == "elbow" and (names[:-1] != want or m.nq != 1)):
                raise MujocoUnavailable(f"{joint} model: expected muscles {want}, found "
                                        f"{m.nq} joints and {names}")
            _base[joint] = m
        return _base[joint]


@dataclass
class ConfiguredModel:
    """A participant's own copy of the model and what the simulator derives from it."""

    model: Any
    """mujoco.MjModel (private: fatigue changes its gains)."""
    q_fixture_rad: float
    inertia_kgm2: float
    """Limb's moment of inertia about the measured joint at the fixture angle (with
    armature and the coupled degrees of freedom of a MyoLeg knee)."""
    K_Nm_rad: float
    B_Nms_rad: float
    B_sensed_Nms_rad: float
    lever_m: float | None
    """Cuff lever (force, N); None: a dynamometer's torque (N m)."""
    F0_N: np.ndarray
    """Maximal isometric force of each muscle (unfatigued), in the model's actuator order."""
    rest_state: np.ndarray
    """Full physics state at rest on the fixture (no stimulation)."""
    q_rest_rad: float
    srs_Nm_rad: np.ndarray
    """Joint stiffness per unit excitation of each muscle (short-range stiffness), in the
    model's actuator order."""
    q_col: int = 1
    """Column of the measured joint's angle in a full-physics state row."""
    v_col: int = 2
    """Column of its velocity."""
    drive_ctrl: tuple[int, ...] = ()
    """Actuator index of each drive (the joint's muscles, extensors first); empty: the
    same order."""

    def endpoint_force_N(self, q_rad: np.ndarray, qdot_rad_s: np.ndarray) -> np.ndarray:
        """What the sensor reads, extension positive, tared at rest: the cuff force (N) or,
        on a dynamometer, the joint torque (N m)."""
        torque = self.K_Nm_rad * (self.q_rest_rad - q_rad) - self.B_sensed_Nms_rad * qdot_rad_s
        return torque if self.lever_m is None else torque / self.lever_m


def _posed(mujoco, m, jid: int, q: float) -> np.ndarray:
    """``qpos`` with the measured joint at ``q`` and the joints coupled to it by the
    model's polynomial equality constraints (a MyoLeg knee's tibia and patella) where the
    constraints put them."""
    qpos = np.array(m.qpos0)
    x0 = m.qpos0[m.jnt_qposadr[jid]]
    qpos[m.jnt_qposadr[jid]] = q
    for e in range(m.neq):
        if m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT and m.eq_obj2id[e] == jid:
            c = m.eq_data[e, :5]
            a1 = m.jnt_qposadr[m.eq_obj1id[e]]
            x = q - x0
            qpos[a1] = m.qpos0[a1] + sum(c[k] * x ** k for k in range(5))
    return qpos


def configure(mount: FixtureMount, tau_act_s: float, tau_deact_s: float,
              fs_Hz: float, stiffening: CoactivationStiffness | None = None,
              joint: str = "elbow") -> ConfiguredModel:
    """A private copy of ``joint``'s model (:func:`load_model`) set up for one
    participant and sampling rate."""
    mujoco, _, rollout = _import_mujoco()
    if not (0.001 <= tau_act_s <= 0.5 and 0.001 <= tau_deact_s <= 0.5):
        raise SimConfigError(f"activation time constants must lie in [1, 500] ms, got "
                             f"{tau_act_s * 1e3:g} / {tau_deact_s * 1e3:g} ms")
    if not (200.0 <= fs_Hz <= 20000.0):
        raise SimConfigError(f"fs_Hz {fs_Hz!r}: the musculoskeletal participant steps "
                             "MuJoCo once per sample; use 200-20000 Hz")
    if (mount.lever_m is None) != (joint != "elbow"):
        raise SimConfigError(f"{joint}: the mount's lever_m must be "
                             + ("a cuff lever (the elbow's force)" if joint == "elbow"
                                else "None (a dynamometer's torque)"))
    m = copy.deepcopy(load_model(joint))
    m.opt.timestep = 1.0 / fs_Hz
    m.opt.gravity[:] = 0.0
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    jname = "r_elbow_flex" if joint == "elbow" else MYOLEG_JOINT[joint]
    jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, jname)
    qa, da = int(m.jnt_qposadr[jid]), int(m.jnt_dofadr[jid])
    q0 = math.radians(mount.angle_deg)
    lo, hi = m.jnt_range[jid]
    if not lo < q0 < hi:
        raise SimConfigError(f"mount angle_deg {mount.angle_deg:g} is outside the model's "
                             f"{jname} range {math.degrees(lo):.0f}-{math.degrees(hi):.0f} deg")
    m.dof_armature[da] += mount.added_inertia_kgm2     # a dynamometer's arm / footplate
    d = mujoco.MjData(m)
    nm = m.nu - 1
    lengths, poses = [], []
    for dq in (-1e-6, 1e-6):              # moment arm = d(length)/dq at the fixture angle
        d.qpos[:] = _posed(mujoco, m, jid, q0 + dq)
        poses.append(np.array(d.qpos))
        mujoco.mj_forward(m, d)
        lengths.append(np.array(d.actuator_length[:nm]))
    moment = (lengths[1] - lengths[0]) / 2e-6
    jac = (poses[1] - poses[0]) / 2e-6   # d qpos / dq (hinge and slide joints: nq == nv)
    d.qpos[:] = _posed(mujoco, m, jid, q0)
    mujoco.mj_forward(m, d)
    L0 = ((m.actuator_lengthrange[:nm, 1] - m.actuator_lengthrange[:nm, 0])
          / (m.actuator_gainprm[:nm, 1] - m.actuator_gainprm[:nm, 0]))   # MuJoCo's L0
    st = stiffening or CoactivationStiffness()
    srs = st.gamma * moment ** 2 * m.actuator_gainprm[:nm, 2] / L0
    Mv = np.zeros(m.nv)
    mujoco.mj_mulM(m, d, Mv, jac)
    inertia = float(jac @ Mv)            # the limb's inertia seen by the measured joint
    K, B = mount.stiffness_damping(inertia)
    m.jnt_stiffness[jid] = K
    m.qpos_spring[qa] = q0
    m.dof_damping[da] = B
    m.actuator_dynprm[:nm, 0] = tau_act_s
    m.actuator_dynprm[:nm, 1] = tau_deact_s
    m.actuator_dynprm[nm, 0] = tau_act_s
    m.actuator_gainprm[nm, :3] = (q0, -1.0, -st.damping_s)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(m)
    d.qpos[:] = _posed(mujoco, m, jid, q0)
    mujoco.mj_forward(m, d)
    state = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state, spec)
    q_col, v_col = 1 + qa, 1 + m.nq + da
    n = int(round(REST_SETTLE_S * fs_Hz))
    for _ in range(3):     # the strap is set so that the relaxed limb rests at q0
        out, _ = rollout.rollout(m, d, state, np.zeros((n, m.nu)))
        m.qpos_spring[qa] += q0 - out[0, -1, q_col]
    out, _ = rollout.rollout(m, d, state, np.zeros((n, m.nu)))
    rest = np.array(out[0, -1])
    rest[0] = 0.0                         # time
    m.actuator_gainprm[nm, 0] = rest[q_col]   # short-range stiffness about the rest angle
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(nm)]
    order = tuple(names.index(mu) for mu in joint_muscles(joint))
    return ConfiguredModel(model=m, q_fixture_rad=q0, inertia_kgm2=inertia, K_Nm_rad=K,
                           B_Nms_rad=B, B_sensed_Nms_rad=B * mount.sensed_damping_fraction,
                           lever_m=mount.lever_m, F0_N=np.array(m.actuator_gainprm[:nm, 2]),
                           rest_state=rest, q_rest_rad=float(rest[q_col]), srs_Nm_rad=srs,
                           q_col=q_col, v_col=v_col,
                           drive_ctrl=() if order == tuple(range(nm)) else order)


class Stepper:
    """Runs a configured model over control sequences with ``mujoco.rollout`` (one C call
    per segment, no Python per step)."""

    def __init__(self, cm: ConfiguredModel):
        mujoco, _, rollout = _import_mujoco()
        self._rollout = rollout.rollout
        self.cm = cm
        self.data = mujoco.MjData(cm.model)

    def run(self, state: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
        """States after each of ``len(ctrl)`` steps from ``state`` (rows: time, q, qdot,
        activations)."""
        if len(ctrl) == 0:
            return np.zeros((0, state.size))
        out, _ = self._rollout(self.cm.model, self.data, state, np.ascontiguousarray(ctrl))
        return out[0]

    def set_force_scale(self, scale: np.ndarray) -> None:
        """Scale each muscle's maximal active force (fatigue); passive force unchanged."""
        self.cm.model.actuator_gainprm[:len(scale), 2] = self.cm.F0_N * scale
