"""The FMU's variables, in one table from which both the model description and the C
header's value references and start values are written (so the two cannot disagree).

FMI 2.0 terms (Functional Mock-up Interface 2.0.x, section 2.2.7 "Definition of Model
Variables"): causality, variability, initial; value references are per base type.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from nmsid.analysis.twin import Twin
from nmsid.sim_backends.effects import effects_from_list

CURVE_CODES = {"constant": 0, "linear": 1, "quadratic": 2, "exponential": 3}
RECRUITMENT_CODES = {None: 0, "power": 1, "sigmoid": 2, "threshold_saturation": 3}
FATIGUE_CODES = {None: 0, "exponential": 1, "linear": 2}
STATE_NAMES = ("a_ext", "y_ext_N", "dy_ext_N_per_s", "a_flex", "y_flex_N",
               "dy_flex_N_per_s", "stim_time_s")
STATE_UNITS = ("N", "N", "N/s", "N", "N", "N/s", "s")


@dataclass(frozen=True)
class Var:
    """One scalar variable."""

    name: str
    c_name: str
    type: str               # Real, Integer, Boolean
    causality: str
    variability: str
    start: float | int | bool | None
    description: str
    unit: str | None = None
    initial: str | None = None
    derivative_of: str | None = None
    key: str = ""
    """The variable's name in a one-joint FMU (its role; ``name`` when empty)."""
    joint: int = 0
    """The joint it belongs to: its position among the FMU's joints."""

    @property
    def role(self) -> str:
        """The variable's name in a one-joint FMU (``force_N``, ``sE``, ``a_ext``, ...)."""
        return self.key or self.name


def _curve_vars(key: str, label: str, unit: str, curve) -> list[Var]:
    coef = list(curve.coefficients) + [0.0] * (3 - len(curve.coefficients))
    # sE is dimensionless: every coefficient has the parameter's unit, except the rate b
    # of the exponential model a exp(b sE)
    units = [unit, "1" if curve.model == "exponential" else unit, unit]
    return [Var(f"{key}_c{i}", f"{key}_c{i}", "Real", "parameter", "fixed", float(coef[i]),
                f"{label} curve coefficient {i} (model given by {key}_model; "
                "constant a, linear a + b sE, quadratic a + b sE + c sE^2, exponential "
                "a exp(b sE); unused coefficients are 0)", units[i], "exact")
            for i in range(3)]


def variables(twin: Twin, *, extrapolate: bool = False) -> list[Var]:
    """Every scalar variable of the FMU for this twin, Reals first (value reference =
    position among its type)."""
    lo, hi = twin.sE_range
    # the C step's parameters of each effect it implements (by name: the C interface)
    effects: dict[str, Any] = {e.name: e for e in effects_from_list(twin.effects)}
    rec = effects.get("recruitment_nonlinearity")
    act = effects.get("activation_dynamics")
    asym = effects.get("flexor_extensor_asymmetry")
    fat = effects.get("fatigue")
    dead = effects.get("dead_time")
    rule = ("evaluated at sE itself (extrapolate = true)" if extrapolate else
            f"clamped to the tested range [{lo:g}, {hi:g}]")
    reals = [
        Var("rE", "rE", "Real", "input", "continuous", 0.5,
            "EAA ratio rE (extensor share of the stimulation, 0..1; 0.5 = balanced, the "
            "rest state)", "1"),
        Var("sE", "sE", "Real", "input", "continuous", float(0.5 * (lo + hi)),
            f"EAA sum sE (co-activation); the twin's curves are {rule} outside "
            f"[{lo:g}, {hi:g}] (parameter extrapolate)", "1"),
        Var("force_N", "force_N", "Real", "output", "continuous", None,
            "endpoint force: offset_N(sE) + fatigue gain x dynamic response", "N",
            "calculated"),
        Var("Kp", "Kp", "Real", "output", "continuous", None,
            "static gain Kp at the current sE (N per unit rE)", "N", "calculated"),
        Var("wn_rad_s", "wn_rad_s", "Real", "output", "continuous", None,
            "natural angular frequency at the current sE", "rad/s", "calculated"),
        Var("zeta", "zeta", "Real", "output", "continuous", None,
            "damping ratio at the current sE", "1", "calculated"),
    ]
    for i, (n, u) in enumerate(zip(STATE_NAMES, STATE_UNITS, strict=True)):
        reals.append(Var(n, f"x{i}", "Real", "local", "continuous", None,
                         "state: " + ("cumulative stimulation time (sE > 0)" if i == 6 else
                                      f"{'extensor' if i < 3 else 'flexor'} path "
                                      f"{['activation', 'force', 'force rate'][i % 3]}"),
                         u, "calculated"))
    for i, (n, u) in enumerate(zip(STATE_NAMES, STATE_UNITS, strict=True)):
        du = {"N": "N/s", "N/s": "N/s2", "s": "1"}[u]
        reals.append(Var(f"der({n})", f"dx{i}", "Real", "local", "continuous", None,
                         f"time derivative of {n}", du, "calculated", derivative_of=n))
    reals += _curve_vars("Kp", "Kp (N)", "N", twin.parameters["Kp"])
    reals += _curve_vars("wn", "wn_rad_s (rad/s)", "rad/s", twin.parameters["wn_rad_s"])
    reals += _curve_vars("zeta", "zeta", "1", twin.parameters["zeta"])
    reals += _curve_vars("offset", "offset_N (N)", "N", twin.offset_N)
    par = [
        ("sE_min", float(lo), "low end of the tested sE range", "1"),
        ("sE_max", float(hi), "high end of the tested sE range", "1"),
        ("rest_lead_s", 0.0, "the inputs ramp from rest (rE = 0.5) to their start values "
         "over this time before the start (0: at rest at the start; `nmsid twin simulate` "
         "uses one sampling period)", "s"),
        ("dead_time_s", float(dead.L_s) if dead else 0.0,
         "effect dead_time: the dynamics respond to the inputs this late (0 = off)", "s"),
        ("activation_tau_s", float(act.tau_s) if act else 0.0,
         "effect activation_dynamics: first-order lag of each muscle's activation (0 = off)",
         "s"),
        ("asym_wn_ratio", float(asym.wn_ratio) if asym else 1.0,
         "effect flexor_extensor_asymmetry: flexor wn / extensor wn (1 = symmetric)", "1"),
        ("asym_zeta_ratio", float(asym.zeta_ratio) if asym else 1.0,
         "effect flexor_extensor_asymmetry: flexor zeta / extensor zeta (1 = symmetric)",
         "1"),
        ("recruitment_p1", float(_rec_params(rec)[0]),
         "effect recruitment_nonlinearity: gamma (power), slope (sigmoid) or threshold "
         "(threshold_saturation)", "1"),
        ("recruitment_p2", float(_rec_params(rec)[1]),
         "effect recruitment_nonlinearity: midpoint (sigmoid) or saturation "
         "(threshold_saturation)", "1"),
        ("fatigue_gain_loss_pct", float(fat.gain_loss_pct) if fat else 0.0,
         "effect fatigue: gain lost over fatigue_reference_stim_s of stimulation", "%"),
        ("fatigue_reference_stim_s", float(fat.reference_stim_s) if fat else 675.0,
         "effect fatigue: reference cumulative stimulation time", "s"),
    ]
    reals += [Var(n, n, "Real", "parameter", "fixed", v, d, u, "exact") for n, v, d, u in par]
    ints = [Var(f"{k}_model", f"{k}_model", "Integer", "parameter", "fixed",
                CURVE_CODES[c.model], f"{label} curve model: 0 constant, 1 linear, "
                "2 quadratic, 3 exponential", None, "exact")
            for k, label, c in (("Kp", "Kp", twin.parameters["Kp"]),
                                ("wn", "wn_rad_s", twin.parameters["wn_rad_s"]),
                                ("zeta", "zeta", twin.parameters["zeta"]),
                                ("offset", "offset_N", twin.offset_N))]
    ints.append(Var("recruitment_shape", "recruitment_shape", "Integer", "parameter", "fixed",
                    RECRUITMENT_CODES[rec.shape.value if rec else None],
                    "effect recruitment_nonlinearity: 0 off (linear), 1 power, 2 sigmoid, "
                    "3 threshold_saturation", None, "exact"))
    ints.append(Var("fatigue_shape", "fatigue_shape", "Integer", "parameter", "fixed",
                    FATIGUE_CODES[fat.shape.value if fat else None],
                    "effect fatigue: 0 off, 1 exponential, 2 linear", None, "exact"))
    bools = [Var("extrapolate", "extrapolate", "Boolean", "parameter", "fixed",
                 bool(extrapolate), "evaluate the curves at sE outside the tested range "
                 "(false: clamp sE to [sE_min, sE_max], as `nmsid twin simulate` does by "
                 "default)", None, "exact")]
    return _in_joint_unit(reals, twin) + ints + bools


_TORQUE_UNITS = {"N": "N.m", "N/s": "N.m/s", "N/s2": "N.m/s2"}
"""A torque twin's units for a force twin's (FMI unit names, ``description._UNITS``)."""


def _in_joint_unit(reals: list[Var], twin: Twin) -> list[Var]:
    """A torque joint's twin (``docs/joints.md``): every force unit in N m and the output
    described as the joint's torque; the variables' names (the FMU's interface) stay."""
    if getattr(twin, "measured_unit", "N") != "N m":
        return reals
    joint = getattr(twin, "joint", "")
    out = []
    for v in reals:
        desc = v.description.replace("endpoint force", f"{joint} joint torque".strip()) \
            .replace("(N per unit rE)", "(N m per unit rE)").replace("(N)", "(N m)")
        out.append(replace(v, unit=_TORQUE_UNITS.get(v.unit, v.unit) if v.unit else v.unit,
                           description=desc))
    return out


def joint_variable_name(name: str, twin: Twin) -> str:
    """A variable's name in an FMU of several joints: the one-joint name with ``_<joint>``
    after it (``rE_knee``, ``Kp_c0_knee``, ``der(a_ext_knee)``), and ``force_N`` named
    for its quantity: ``force_N_elbow``, ``torque_Nm_knee``.

    Examples
    --------
    >>> from nmsid.analysis.twin import Curve
    >>> c = {"Kp": Curve("constant", [5.0]), "wn_rad_s": Curve("constant", [30.0]),
    ...      "zeta": Curve("constant", [0.7])}
    >>> knee = Twin("P01", c, (0.3, 1.0), joint="knee", measured_quantity="torque",
    ...             measured_unit="N m")
    >>> [joint_variable_name(n, knee) for n in ("rE", "force_N", "der(y_ext_N)")]
    ['rE_knee', 'torque_Nm_knee', 'der(y_ext_N_knee)']
    """
    j = twin.joint
    if name.startswith("der(") and name.endswith(")"):
        return f"der({joint_variable_name(name[4:-1], twin)})"
    if name == "force_N":
        return f"torque_Nm_{j}" if twin.measured_unit == "N m" else f"force_N_{j}"
    return f"{name}_{j}"


def joint_variables(twins: list[Twin], *, extrapolate: bool = False) -> list[Var]:
    """Every scalar variable of an FMU of several joints: each joint's variables of a
    one-joint FMU (:func:`variables`), named by :func:`joint_variable_name`, one joint
    after the other, so that joint k's value references are k times a joint's count plus
    the one-joint ones (``c/nmsid_model.h``)."""
    out = []
    for k, twin in enumerate(twins):
        for v in variables(twin, extrapolate=extrapolate):
            out.append(replace(
                v, name=joint_variable_name(v.name, twin), key=v.name, joint=k,
                derivative_of=(joint_variable_name(v.derivative_of, twin)
                               if v.derivative_of else None),
                description=f"{twin.joint}: {v.description}"))
    return out


def _rec_params(rec) -> tuple[float, float]:
    if rec is None:
        return 1.0, 0.0
    shape = rec.shape.value
    if shape == "power":
        return rec.gamma, 0.0
    if shape == "sigmoid":
        return rec.slope, rec.midpoint
    return rec.threshold, rec.saturation


def value_references(vs: list[Var]) -> dict[str, int]:
    """Variable name -> value reference (position among its base type)."""
    out, count = {}, {"Real": 0, "Integer": 0, "Boolean": 0}
    for v in vs:
        out[v.name] = count[v.type]
        count[v.type] += 1
    return out
