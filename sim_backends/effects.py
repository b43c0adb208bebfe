"""The optional unmodelled effects of the virtual participant (all off by default).

Names, parameters and their bounds come from the registry
(:mod:`nmsid.protocols.effects`, as ``docs/twin-file.md`` lists them); an effect list in a
twin file (``[{"name": ..., "params": {...}}, ...]``) parses with :func:`effects_from_list`
and prints back with :func:`effects_to_list`. The simulator applies them in the twin's order
of physics: recruitment -> activation -> (asymmetric) dynamics -> dead time -> fatigue gain
-> baseline.

Examples
--------
>>> effs = effects_from_list([{"name": "dead_time", "params": {"L_s": 0.03}}])
>>> effs[0]
DeadTime(L_s=0.03)
>>> effects_to_list(effs)
[{'name': 'dead_time', 'params': {'L_s': 0.03}}]
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields

import numpy as np

from nmsid.protocols.effects import EFFECT_NAMES, EffectParamError, check_param, spec
from nmsid.protocols.effects import Effect as _Name
from nmsid.sim_backends.errors import SimConfigError


def _checked(obj, *names: str) -> None:
    """Set each named field of the frozen dataclass ``obj`` to its value checked against
    the registry's bounds (:func:`nmsid.protocols.effects.check_param`)."""
    for n in names:
        try:
            object.__setattr__(obj, n, check_param(obj.name, n, getattr(obj, n)))
        except EffectParamError as exc:
            raise SimConfigError(str(exc)) from None


@dataclass(frozen=True)
class DeadTime:
    """The force responds to the stimulation ``L_s`` seconds late."""

    L_s: float
    name = _Name.DEAD_TIME.value

    def __post_init__(self):
        _checked(self, "L_s")


@dataclass(frozen=True)
class ActivationDynamics:
    """An extra first-order lag ``1 / (tau_s s + 1)`` of each muscle's activation."""

    tau_s: float
    name = _Name.ACTIVATION_DYNAMICS.value

    def __post_init__(self):
        _checked(self, "tau_s")


class FatigueShape(enum.Enum):
    EXPONENTIAL = "exponential"
    LINEAR = "linear"


@dataclass(frozen=True)
class Fatigue:
    """Gain multiplied by ``g(c)``, c = cumulative stimulation time since the session began.

    exponential: ``g = (1 - p) ** (c / c_ref)``; linear: ``g = max(0.05, 1 - p c / c_ref)``;
    ``p = gain_loss_pct / 100``, ``c_ref = reference_stim_s`` (675 s = 45 trials x 15 s).
    """

    shape: FatigueShape
    gain_loss_pct: float
    reference_stim_s: float = spec(_Name.FATIGUE).param("reference_stim_s").default_value()
    name = _Name.FATIGUE.value

    def __post_init__(self):
        try:
            object.__setattr__(self, "shape", FatigueShape(getattr(self.shape, "value",
                                                                   self.shape)))
        except ValueError:
            raise SimConfigError(f"fatigue.shape {self.shape!r} is unknown; valid: "
                                 "exponential, linear") from None
        _checked(self, "gain_loss_pct", "reference_stim_s")

    def gain(self, cumulative_stim_s):
        """g(c) for c in seconds of cumulative stimulation (array or scalar)."""
        c = np.asarray(cumulative_stim_s, dtype=float)
        p = self.gain_loss_pct / 100.0
        if self.shape is FatigueShape.EXPONENTIAL:
            g = (1.0 - p) ** (c / self.reference_stim_s)
        else:
            g = np.maximum(0.05, 1.0 - p * c / self.reference_stim_s)
        return float(g) if np.ndim(g) == 0 else g


class RecruitmentShape(enum.Enum):
    POWER = "power"
    SIGMOID = "sigmoid"
    THRESHOLD_SATURATION = "threshold_saturation"


_SHAPE_PARAMS = {RecruitmentShape.POWER: ("gamma",),
                 RecruitmentShape.SIGMOID: ("slope", "midpoint"),
                 RecruitmentShape.THRESHOLD_SATURATION: ("threshold", "saturation")}


@dataclass(frozen=True)
class RecruitmentNonlinearity:
    """Each muscle's normalised intensity I in [0, 1] becomes activation h(I), h(0)=0,
    h(1)=1 (outside [0, 1] h continues with unit slope).

    power: ``I ** gamma``; sigmoid: a logistic of ``slope (I - midpoint)`` rescaled to
    pass through (0, 0) and (1, 1); threshold_saturation: ``clip((I - threshold) /
    (saturation - threshold), 0, 1)``.
    """

    shape: RecruitmentShape
    gamma: float | None = None
    slope: float | None = None
    midpoint: float | None = None
    threshold: float | None = None
    saturation: float | None = None
    name = _Name.RECRUITMENT_NONLINEARITY.value

    def __post_init__(self):
        try:
            shape = RecruitmentShape(getattr(self.shape, "value", self.shape))
        except ValueError:
            raise SimConfigError(
                f"recruitment_nonlinearity.shape {self.shape!r} is unknown; valid: "
                "power, sigmoid, threshold_saturation") from None
        object.__setattr__(self, "shape", shape)
        for p in _SHAPE_PARAMS[shape]:
            if getattr(self, p) is None:
                raise SimConfigError(f"recruitment_nonlinearity with shape {shape.value} "
                                     f"needs {', '.join(_SHAPE_PARAMS[shape])}; {p} missing")
        if shape is RecruitmentShape.POWER:
            _checked(self, "gamma")
        elif shape is RecruitmentShape.SIGMOID:
            _checked(self, "slope", "midpoint")
        else:
            th, sat = float(self.threshold), float(self.saturation)
            if not (0.0 <= th < sat <= 1.0):
                raise SimConfigError(
                    "recruitment_nonlinearity needs 0 <= threshold < saturation <= 1, got "
                    f"threshold={self.threshold!r}, saturation={self.saturation!r}")
            object.__setattr__(self, "threshold", th)
            object.__setattr__(self, "saturation", sat)

    def params(self) -> dict:
        d = {"shape": self.shape.value}
        d.update({p: getattr(self, p) for p in _SHAPE_PARAMS[self.shape]})
        return d

    def h(self, intensity):
        """Activation of normalised intensity (array); unit slope outside [0, 1]."""
        x = np.asarray(intensity, dtype=float)
        xin = np.clip(x, 0.0, 1.0)
        if self.shape is RecruitmentShape.POWER:
            y = xin ** self.gamma
        elif self.shape is RecruitmentShape.SIGMOID:
            lo = _logistic(-self.slope * self.midpoint)
            hi = _logistic(self.slope * (1.0 - self.midpoint))
            y = (_logistic(self.slope * (xin - self.midpoint)) - lo) / (hi - lo)
        else:
            y = np.clip((xin - self.threshold) / (self.saturation - self.threshold), 0, 1)
        return y + (x - xin)


def _logistic(z):
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(z, dtype=float)))


@dataclass(frozen=True)
class BaselineDrift:
    """Slow non-linear wander of the force baseline, band-limited below ``corner_Hz``,
    RMS ``amplitude_N`` (a seeded sum of sinusoids; the seed is the participant's)."""

    amplitude_N: float
    corner_Hz: float
    name = _Name.BASELINE_DRIFT.value

    def __post_init__(self):
        _checked(self, "amplitude_N", "corner_Hz")


@dataclass(frozen=True)
class FlexorExtensorAsymmetry:
    """The flexor's dynamics have wn x ``wn_ratio`` and zeta x ``zeta_ratio``; the
    extensor keeps the nominal ones."""

    wn_ratio: float
    zeta_ratio: float
    name = _Name.FLEXOR_EXTENSOR_ASYMMETRY.value

    def __post_init__(self):
        _checked(self, "wn_ratio", "zeta_ratio")


_CLASSES = {cls.name: cls for cls in (DeadTime, ActivationDynamics, Fatigue,
                                      RecruitmentNonlinearity, BaselineDrift,
                                      FlexorExtensorAsymmetry)}
if set(_CLASSES) != set(EFFECT_NAMES):  # pragma: no cover - a registry entry without a class
    raise ImportError("sim_backends.effects: the dataclasses "
                      f"{sorted(_CLASSES)} differ from the registry {sorted(EFFECT_NAMES)}")

EFFECT_TYPES = {name: _CLASSES[name] for name in EFFECT_NAMES}
"""Effect name (as in twin files) -> dataclass, in the registry's order of physics."""

Effect = (DeadTime | ActivationDynamics | Fatigue | RecruitmentNonlinearity | BaselineDrift
          | FlexorExtensorAsymmetry)


def effect_params(effect) -> dict:
    """The effect's ``params`` object as in twin files (enums as their names)."""
    if isinstance(effect, RecruitmentNonlinearity):
        return effect.params()
    out = {}
    for f in fields(effect):
        v = getattr(effect, f.name)
        out[f.name] = v.value if isinstance(v, enum.Enum) else v
    return out


def effect_from_dict(d: dict):
    """Parse ``{"name": ..., "params": {...}}``.

    Raises
    ------
    SimConfigError
        Unknown name or parameter, missing or invalid value.
    """
    if not isinstance(d, dict) or "name" not in d:
        raise SimConfigError(f"an effect must be an object with 'name' and 'params', got {d!r}")
    name = d["name"]
    cls = EFFECT_TYPES.get(name)
    if cls is None:
        raise SimConfigError(f"effect name {name!r} is unknown; valid: {', '.join(EFFECT_NAMES)}")
    params = dict(d.get("params") or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(params) - known)
    if unknown:
        raise SimConfigError(f"effect {name} has unknown params {unknown}; valid: "
                             f"{sorted(known)}")
    try:
        return cls(**params)
    except TypeError as exc:
        raise SimConfigError(f"effect {name}: {exc}") from None


def effects_from_list(items) -> list:
    """Parse a twin file's ``effects`` list (at most one effect of each name)."""
    out = [e if not isinstance(e, dict) else effect_from_dict(e) for e in (items or [])]
    names = [e.name for e in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SimConfigError(f"effects {dup} are listed more than once; give each once")
    for e in out:
        if type(e) not in EFFECT_TYPES.values():
            raise SimConfigError(f"{e!r} is not an effect; valid: {', '.join(EFFECT_NAMES)}")
    return out


def effects_to_list(effects) -> list[dict]:
    """The twin-file form of a list of effects."""
    return [{"name": e.name, "params": effect_params(e)} for e in effects]


__all__ = ["DeadTime", "ActivationDynamics", "Fatigue", "FatigueShape",
           "RecruitmentNonlinearity", "RecruitmentShape", "BaselineDrift",
           "FlexorExtensorAsymmetry", "EFFECT_TYPES", "EFFECT_NAMES", "effect_from_dict",
           "effects_from_list", "effects_to_list", "effect_params"]
