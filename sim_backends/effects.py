"""The optional unmodelled effects of the virtual participant (all off by default).

Each effect is defined once, in its module of :mod:`nmsid.protocols.effect_defs`, and
listed by the registry (:mod:`nmsid.protocols.effects`); this module parses a twin file's
effect list (``[{"name": ..., "params": {...}}, ...]``) into the registry's parameter
dataclasses (:func:`effects_from_list`) and prints it back (:func:`effects_to_list`), with
the simulator's configuration errors. The simulator composes them at the chain's slots
(:func:`nmsid.protocols.effects.chain_of`) in the registry's order of physics.

Examples
--------
>>> effs = effects_from_list([{"name": "dead_time", "params": {"L_s": 0.03}}])
>>> effs[0]
DeadTime(L_s=0.03)
>>> effects_to_list(effs)
[{'name': 'dead_time', 'params': {'L_s': 0.03}}]
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import fields
from typing import Any

# the built-in effects' parameter dataclasses, re-exported under their usual names
from nmsid.protocols.effect_defs.activation_dynamics import ActivationDynamics
from nmsid.protocols.effect_defs.base import EffectParams
from nmsid.protocols.effect_defs.baseline_drift import BaselineDrift
from nmsid.protocols.effect_defs.dead_time import DeadTime
from nmsid.protocols.effect_defs.fatigue import Fatigue, FatigueShape
from nmsid.protocols.effect_defs.flexor_extensor_asymmetry import FlexorExtensorAsymmetry
from nmsid.protocols.effect_defs.recruitment_nonlinearity import (
    RecruitmentNonlinearity,
    RecruitmentShape,
)
from nmsid.protocols.effects import BY_NAME, EFFECT_NAMES, EffectParamError
from nmsid.sim_backends.errors import SimConfigError


class _Types(Mapping):
    """Effect name -> its parameter dataclass, following the registry."""

    def __getitem__(self, name: str) -> type[EffectParams]:
        return BY_NAME[name].source.params_type

    def __iter__(self) -> Iterator[str]:
        return iter(EFFECT_NAMES)

    def __len__(self) -> int:
        return len(EFFECT_NAMES)


EFFECT_TYPES: Mapping[str, type[EffectParams]] = _Types()
"""Effect name (as in twin files) -> dataclass, in the registry's order of physics."""

#: Any effect's parameter dataclass.
Effect = EffectParams


def effect_params(effect: EffectParams) -> dict:
    """The effect's ``params`` object as in twin files (enums as their names)."""
    return effect.params()


def effect_from_dict(d: Any) -> EffectParams:
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
    known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(params) - known)
    if unknown:
        raise SimConfigError(f"effect {name} has unknown params {unknown}; valid: "
                             f"{sorted(known)}")
    try:
        return cls(**params)
    except EffectParamError as exc:
        raise SimConfigError(str(exc)) from None
    except TypeError as exc:
        raise SimConfigError(f"effect {name}: {exc}") from None


def effects_from_list(items) -> list[EffectParams]:
    """Parse a twin file's ``effects`` list (at most one effect of each name)."""
    out = [e if not isinstance(e, dict) else effect_from_dict(e) for e in (items or [])]
    for e in out:
        if not isinstance(e, EffectParams) or e.name not in BY_NAME:
            raise SimConfigError(f"{e!r} is not an effect; valid: {', '.join(EFFECT_NAMES)}")
    names = [e.name for e in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SimConfigError(f"effects {dup} are listed more than once; give each once")
    return out


def effects_to_list(effects) -> list[dict]:
    """The twin-file form of a list of effects."""
    return [{"name": e.name, "params": effect_params(e)} for e in effects]


__all__ = ["DeadTime", "ActivationDynamics", "Fatigue", "FatigueShape",
           "RecruitmentNonlinearity", "RecruitmentShape", "BaselineDrift",
           "FlexorExtensorAsymmetry", "EFFECT_TYPES", "EFFECT_NAMES", "effect_from_dict",
           "effects_from_list", "effects_to_list", "effect_params", "Effect"]
