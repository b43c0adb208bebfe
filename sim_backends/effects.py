"""The optional unmodelled effects of the virtual participant (all off by default).

Names and parameters are exactly those of ``docs/twin-file.md``; an effect list in a
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
import math
from dataclasses import dataclass, fields

import numpy as np

from nmsid.sim_backends.errors import SimConfigError


def _positive(name: str, value: float, *, allow_zero: bool = False, upper: float | None = None
              ) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SimConfigError(f"{name} must be a number, got {value!r}") from None
    ok = math.isfinite(v) and (v >= 0 if allow_zero else v > 0)
    if upper is not None:
        ok = ok and v <= upper
    if not ok:
        rng = f"{'>= 0' if allow_zero else '> 0'}" + (f" and <= {upper:g}" if upper else "")
        raise SimConfigError(f"{name} must be a finite number {rng}, got {value!r}")
    return v


@dataclass(frozen=True)
class DeadTime:
    """The force responds to the stimulation ``L_s`` seconds late."""

    L_s: float
    name = "dead_time"

    def __post_init__(self):
        object.__setattr__(self, "L_s", _positive("dead_time.L_s", self.L_s,
                                                  allow_zero=True, upper=2.0))


@dataclass(frozen=True)
class ActivationDynamics:
    """An extra first-order lag ``1 / (tau_s s + 1)`` of each muscle's activation."""

    tau_s: float
    name = "activation_dynamics"

    def __post_init__(self):
        object.__setattr__(self, "tau_s", _positive("activation_dynamics.tau_s",
                                                    self.tau_s, allow_zero=True, upper=5.0))


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
    reference_stim_s: float = 675.0
    name = "fatigue"

    def __post_init__(self):
        try:
            object.__setattr__(self, "shape", FatigueShape(getattr(self.shape, "value",
                                                                   self.shape)))
        except ValueError:
            raise SimConfigError(f"fatigue.shape {self.shape!r} is unknown; valid: "
                                 "exponential, linear") from None
        object.__setattr__(self, "gain_loss_pct", _positive(
            "fatigue.gain_loss_pct", self.gain_loss_pct, allow_zero=True, upper=99.0))
        object.__setattr__(self, "reference_stim_s", _positive(
            "fatigue.reference_stim_s", self.reference_stim_s))

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
    name = "recruitment_nonlinearity"

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
            object.__setattr__(self, "gamma", _positive("recruitment_nonlinearity.gamma",
                                                        self.gamma, upper=10.0))
        elif shape is RecruitmentShape.SIGMOID:
            object.__setattr__(self, "slope", _positive("recruitment_nonlinearity.slope",
                                                        self.slope, upper=200.0))
            object.__setattr__(self, "midpoint", float(self.midpoint))
            if not math.isfinite(self.midpoint):
                raise SimConfigError("recruitment_nonlinearity.midpoint must be finite")
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
    name = "baseline_drift"

    def __post_init__(self):
        object.__setattr__(self, "amplitude_N", _positive(
            "baseline_drift.amplitude_N", self.amplitude_N, allow_zero=True, upper=100.0))
        object.__setattr__(self, "corner_Hz", _positive(
            "baseline_drift.corner_Hz", self.corner_Hz, upper=50.0))


@dataclass(frozen=True)
class FlexorExtensorAsymmetry:
    """The flexor's dynamics have wn x ``wn_ratio`` and zeta x ``zeta_ratio``; the
    extensor keeps the nominal ones."""

    wn_ratio: float
    zeta_ratio: float
    name = "flexor_extensor_asymmetry"

    def __post_init__(self):
        object.__setattr__(self, "wn_ratio", _positive(
            "flexor_extensor_asymmetry.wn_ratio", self.wn_ratio, upper=10.0))
        object.__setattr__(self, "zeta_ratio", _positive(
            "flexor_extensor_asymmetry.zeta_ratio", self.zeta_ratio, upper=10.0))


EFFECT_TYPES = {cls.name: cls for cls in (DeadTime, ActivationDynamics, Fatigue,
                                          RecruitmentNonlinearity, BaselineDrift,
                                          FlexorExtensorAsymmetry)}
"""Effect name (as in twin files) -> dataclass."""

EFFECT_NAMES = tuple(EFFECT_TYPES)

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
