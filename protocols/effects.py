"""The registry of unmodelled effects: each declared once, here.

An effect is something the nominal second-order model leaves out that the simulator can
add to a virtual participant, the gap diagnosis can fit and name, a twin file can carry and
the FMU can run (``docs/twin-file.md``). This module declares, for each one, its name (the
twin file's), its parameters with their units and bounds, and its continuous-time
definition; everything else is derived from it or held to it by tests:

- :class:`Effect` (the names) is what ``nmsid.analysis.gap`` fits and reports and what
  ``nmsid.sim_backends.effects`` registers its dataclasses under;
- :func:`check_param` is the one bounds check of a parameter, used by the simulator's
  dataclasses (so a twin file is refused with the bounds stated here);
- ``tests/protocols/test_effects.py`` holds the simulator's dataclasses, the gap
  diagnosis's fitted forms and the FMU's reference step to this list.

The order of :data:`EFFECTS` is the order of physics in which the simulator and the FMU
apply them: recruitment -> activation -> (asymmetric) dynamics -> dead time -> fatigue
gain -> baseline. Adding an effect: docs/architecture.md, "Adding an effect".

Examples
--------
>>> [e.value for e in Effect][:3]
['none', 'recruitment_nonlinearity', 'activation_dynamics']
>>> spec("dead_time").param("L_s").bounds_text()
'>= 0 and <= 2'
>>> check_param("dead_time", "L_s", 0.03)
0.03
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum


class EffectParamError(ValueError):
    """A value of an effect parameter is outside what the registry allows.

    The message names the parameter (``effect.param``), the value and the valid range; the
    simulator re-raises it as its own configuration error.
    """


class Effect(str, Enum):
    """An effect's name as twin files, the simulator and the gap report write it
    (``NONE``: the nominal model, no effect)."""

    NONE = "none"
    RECRUITMENT_NONLINEARITY = "recruitment_nonlinearity"
    ACTIVATION_DYNAMICS = "activation_dynamics"
    FLEXOR_EXTENSOR_ASYMMETRY = "flexor_extensor_asymmetry"
    DEAD_TIME = "dead_time"
    FATIGUE = "fatigue"
    BASELINE_DRIFT = "baseline_drift"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect, as a twin file writes it.

    Attributes
    ----------
    name : str
        The twin file's key (unit in the name where it has one).
    meaning : str
        What it is, in words.
    lower, upper : float or None
        Bounds (None: unbounded on that side). ``lower_open``: ``lower`` itself refused.
    choices : tuple of str
        For a categorical parameter (a shape): its valid values; bounds are unused.
    required : bool
        False when a default applies (``default``) or when only some shapes need it.
    """

    name: str
    meaning: str
    lower: float | None = None
    upper: float | None = None
    lower_open: bool = False
    choices: tuple[str, ...] = ()
    required: bool = True
    default: float | None = None

    def default_value(self) -> float:
        """The default of an optional numeric parameter (KeyError if it has none)."""
        if self.default is None:
            raise KeyError(f"parameter {self.name} has no default")
        return float(self.default)

    def bounds_text(self) -> str:
        """The valid range in words (``'> 0 and <= 10'``)."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        parts = []
        if self.lower is not None:
            parts.append(f"{'>' if self.lower_open else '>='} {self.lower:g}")
        if self.upper is not None:
            parts.append(f"<= {self.upper:g}")
        return " and ".join(parts) or "a finite number"

    def contains(self, value: float) -> bool:
        """True if ``value`` is finite and within the bounds."""
        if not math.isfinite(value):
            return False
        if self.lower is not None and (value <= self.lower if self.lower_open
                                       else value < self.lower):
            return False
        return self.upper is None or value <= self.upper


@dataclass(frozen=True)
class EffectSpec:
    """One effect: its name, parameters and continuous-time definition.

    Attributes
    ----------
    effect : Effect
    summary : str
        One line: what the participant does that the nominal model does not.
    definition : str
        The continuous-time definition, in the notation of docs/twin-file.md (rE, sE,
        ``I_e = rE sE``, ``I_f = (1 - rE) sE``, the nominal ``G(s) = wn^2 / (s^2 + 2 zeta wn
        s + wn^2)``, cumulative stimulation time ``c``).
    params : tuple of ParamSpec
    """

    effect: Effect
    summary: str
    definition: str
    params: tuple[ParamSpec, ...]

    @property
    def name(self) -> str:
        return self.effect.value

    def param(self, name: str) -> ParamSpec:
        """The parameter called ``name`` (KeyError if the effect has none)."""
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(f"effect {self.name} has no parameter {name!r}; valid: "
                       f"{', '.join(p.name for p in self.params)}")

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)


#: Every effect, in the order of physics (the order the simulator and the FMU apply them).
EFFECTS: tuple[EffectSpec, ...] = (
    EffectSpec(
        Effect.RECRUITMENT_NONLINEARITY,
        "each muscle's activation is a monotone, non-linear function of its intensity",
        "a_e = h(I_e), a_f = h(I_f) with h(0) = 0, h(1) = 1 on the normalised intensity "
        "(unit slope outside [0, 1]); net drive (h(I_e) - h(I_f)) / (2 sE). "
        "power: h = I^gamma; sigmoid: logistic(slope (I - midpoint)) rescaled through (0, 0) "
        "and (1, 1); threshold_saturation: clip((I - threshold) / (saturation - threshold), "
        "0, 1)",
        (ParamSpec("shape", "the curve's family",
                   choices=("power", "sigmoid", "threshold_saturation")),
         ParamSpec("gamma", "power: the exponent", 0.0, 10.0, lower_open=True,
                   required=False),
         ParamSpec("slope", "sigmoid: steepness per unit intensity", 0.0, 200.0,
                   lower_open=True, required=False),
         ParamSpec("midpoint", "sigmoid: intensity at half rise", required=False),
         ParamSpec("threshold", "threshold_saturation: intensity where force begins",
                   0.0, 1.0, required=False),
         ParamSpec("saturation", "threshold_saturation: intensity where force stops rising",
                   0.0, 1.0, required=False))),
    EffectSpec(
        Effect.ACTIVATION_DYNAMICS,
        "each muscle's activation lags its drive by a first-order filter",
        "a(s) = u(s) / (tau_s s + 1) for each muscle, so the force is "
        "G(s) / (tau_s s + 1) of the drive",
        (ParamSpec("tau_s", "the activation time constant, s", 0.0, 5.0),)),
    EffectSpec(
        Effect.FLEXOR_EXTENSOR_ASYMMETRY,
        "the flexor's dynamics differ from the extensor's",
        "F = Kp (G_e(s) u_e - G_f(s) u_f) with G_e = G(wn, zeta) and "
        "G_f = G(wn wn_ratio, zeta zeta_ratio)",
        (ParamSpec("wn_ratio", "flexor wn / extensor wn", 0.0, 10.0, lower_open=True),
         ParamSpec("zeta_ratio", "flexor zeta / extensor zeta", 0.0, 10.0,
                   lower_open=True))),
    EffectSpec(
        Effect.DEAD_TIME,
        "the force answers the stimulation late",
        "F(t) = F_0(t - L_s), i.e. G(s) e^{-L_s s}",
        (ParamSpec("L_s", "the delay, s", 0.0, 2.0),)),
    EffectSpec(
        Effect.FATIGUE,
        "the force's gain falls with cumulative stimulation",
        "F = g(c) F_0 with p = gain_loss_pct / 100; exponential: g = (1 - p)^(c / "
        "reference_stim_s); linear: g = max(0.05, 1 - p c / reference_stim_s)",
        (ParamSpec("shape", "the decline's form", choices=("exponential", "linear")),
         ParamSpec("gain_loss_pct", "gain lost over reference_stim_s, %", 0.0, 99.0),
         ParamSpec("reference_stim_s", "cumulative stimulation the loss refers to, s",
                   0.0, None, lower_open=True, required=False, default=675.0))),
    EffectSpec(
        Effect.BASELINE_DRIFT,
        "the force baseline wanders slowly and non-linearly",
        "F = F_0 + b(t), b band-limited below corner_Hz with RMS amplitude_N",
        (ParamSpec("amplitude_N", "RMS of the wander, N", 0.0, 100.0),
         ParamSpec("corner_Hz", "highest frequency of the wander, Hz", 0.0, 50.0,
                   lower_open=True))),
)

#: Effect name -> its spec.
BY_NAME: dict[str, EffectSpec] = {s.name: s for s in EFFECTS}

#: The effect names in the order of physics.
EFFECT_NAMES: tuple[str, ...] = tuple(BY_NAME)

#: The effects the gap diagnosis tries (all of them), in the order of physics.
CANDIDATES: tuple[Effect, ...] = tuple(s.effect for s in EFFECTS)


def spec(effect: Effect | str) -> EffectSpec:
    """The registry entry of ``effect`` (a name or an :class:`Effect`).

    Raises
    ------
    EffectParamError
        Unknown name (the message lists the valid ones).
    """
    name = effect.value if isinstance(effect, Effect) else str(effect)
    try:
        return BY_NAME[name]
    except KeyError:
        raise EffectParamError(f"effect name {name!r} is unknown; valid: "
                               f"{', '.join(EFFECT_NAMES)}") from None


def check_param(effect: Effect | str, name: str, value) -> float:
    """``value`` as a float if the registry's bounds allow it for ``effect.name``.

    Raises
    ------
    EffectParamError
        Not a number, not finite or out of bounds; the message says what is valid.
    """
    p = spec(effect).param(name)
    label = f"{spec(effect).name}.{name}"
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise EffectParamError(f"{label} must be a number, got {value!r}") from None
    if not p.contains(v):
        raise EffectParamError(f"{label} must be a finite number {p.bounds_text()}, "
                               f"got {value!r}")
    return v


__all__ = ["Effect", "EffectSpec", "ParamSpec", "EffectParamError", "EFFECTS", "BY_NAME",
           "EFFECT_NAMES", "CANDIDATES", "spec", "check_param"]
