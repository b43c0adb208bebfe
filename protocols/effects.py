"""The registry of unmodelled effects: the list of effect modules, in the order of physics.

An effect is something the nominal second-order model leaves out that the simulator can
add to a virtual participant, the gap diagnosis can fit and name, a twin file can carry and
the FMU can run (``docs/twin-file.md``). Each is defined once, in its own module of
:mod:`nmsid.protocols.effect_defs` (name, parameters with units and bounds, its
continuous-time definition as functions at the chain's slots, its fitted form; see
:mod:`nmsid.protocols.effect_defs.base`). This module lists them (:data:`EFFECT_MODULES`,
the one registry entry of an effect) and derives what the rest of nmsid reads:

- :class:`Effect` (the names) is what ``nmsid.analysis.gap`` fits and reports, what the
  simulator and twin files call the effects;
- :func:`params_type` (the parameter dataclass the simulator builds from a twin file),
  :func:`form` (what the gap fit fits), :func:`chain_of` (the effects composed at the
  chain's slots, for the simulator and the FMU's reference step);
- :func:`check_param`, the one bounds check of a parameter.

The order of :data:`EFFECT_MODULES` is the order of physics: recruitment -> activation ->
(asymmetric) dynamics -> dead time -> fatigue gain -> baseline. :func:`register` adds an
effect at run time (a lab's own, or a test's). Adding an effect: docs/architecture.md,
"Adding an effect".

Examples
--------
>>> [e.value for e in Effect][:3]
['none', 'recruitment_nonlinearity', 'activation_dynamics']
>>> spec("dead_time").param("L_s").bounds_text()
'>= 0 and <= 2'
>>> check_param("dead_time", "L_s", 0.03)
0.03
>>> chain_of([params_type("dead_time")(L_s=0.03)]).delay_s
0.03
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmsid.protocols.effect_defs import (
    activation_dynamics,
    baseline_drift,
    dead_time,
    fatigue,
    flexor_extensor_asymmetry,
    recruitment_nonlinearity,
)
from nmsid.protocols.effect_defs.base import (
    SLOTS,
    EffectDefinition,
    EffectParamError,
    EffectParams,
    FittedForm,
    ParamSpec,
)

#: THE REGISTRY: every effect's module, in the order of physics (the simulator and the FMU
#: apply them in this order). Adding an effect = its module + one line here.
EFFECT_MODULES = (
    recruitment_nonlinearity,
    activation_dynamics,
    flexor_extensor_asymmetry,
    dead_time,
    fatigue,
    baseline_drift,
)

_REGISTRY: list[EffectDefinition] = [m.EFFECT for m in EFFECT_MODULES]
_version = [0]


def _bump() -> None:
    _version[0] += 1
    _snapshot.cache_clear()
    _chain.cache_clear()


# -- the names ---------------------------------------------------------------------------

class _EffectMeta(type):
    """``Effect.DEAD_TIME`` (any registered name in capitals), ``for e in Effect``."""

    def __getattr__(cls, attr: str) -> Effect:
        name = attr.lower()
        if attr.isupper() and (name == "none" or name in {d.name for d in _REGISTRY}):
            return cls(name)  # type: ignore[no-any-return]
        raise AttributeError(f"no effect called {name!r}; valid: "
                             f"{', '.join(_snapshot().names)}")

    def __iter__(cls) -> Iterator[Effect]:
        return iter((cls("none"), *_snapshot().effects))

    def __len__(cls) -> int:
        return 1 + len(_snapshot().names)


class Effect(str, metaclass=_EffectMeta):
    """An effect's name as twin files, the simulator and the gap report write it
    (``Effect.NONE``: the nominal model, no effect); one object per name, so ``is`` works.

    ``Effect("dead_time")`` or ``Effect.DEAD_TIME``; an unknown name is a
    :class:`EffectParamError` (a ``ValueError``) listing the valid ones.
    """

    __slots__ = ()
    _interned: dict[str, Effect] = {}

    def __new__(cls, name: Any) -> Effect:
        key = str(name.value if isinstance(name, Effect) else name)
        out = cls._interned.get(key)
        if out is not None:
            return out
        if key != "none" and key not in {d.name for d in _REGISTRY}:
            raise EffectParamError(f"effect name {key!r} is unknown; valid: "
                                   f"{', '.join(d.name for d in _REGISTRY)}")
        out = str.__new__(cls, key)
        cls._interned[key] = out
        return out

    def __reduce__(self) -> tuple[type[Effect], tuple[str]]:
        # every pickle protocol and copy: back through __new__, so the name stays one object
        return (Effect, (self.value,))

    @property
    def value(self) -> str:
        """The name (as a plain string)."""
        return str.__str__(self)

    def __repr__(self) -> str:
        return f"<Effect {self.value}>"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


# -- the specs -------------------------------------------------------------------------

@dataclass(frozen=True)
class EffectSpec:
    """One effect: its name, parameters and continuous-time definition (read from its
    module).

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
    source : EffectDefinition
        The module's definition (parameter dataclass and fitted form).
    """

    effect: Effect
    summary: str
    definition: str
    params: tuple[ParamSpec, ...]
    source: EffectDefinition

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

@dataclass(frozen=True)
class _Snapshot:
    specs: tuple[EffectSpec, ...]
    by_name: dict[str, EffectSpec]
    names: tuple[str, ...]
    effects: tuple[Effect, ...]


@functools.lru_cache(maxsize=1)
def _snapshot() -> _Snapshot:
    names = tuple(d.name for d in _REGISTRY)
    effects = tuple(Effect(n) for n in names)
    specs = tuple(EffectSpec(e, d.params_type.summary, d.params_type.definition,
                             d.params_type.param_specs(), d)
                  for e, d in zip(effects, _REGISTRY, strict=True))
    return _Snapshot(specs, {s.name: s for s in specs}, names, effects)


class _LiveSequence(Sequence):
    """A read-only view of the registry that follows :func:`register`."""

    def __init__(self, get: Callable[[], tuple]):
        self._get = get

    def __getitem__(self, i):  # type: ignore[override]
        return self._get()[i]

    def __len__(self) -> int:
        return len(self._get())

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and tuple(self) == tuple(other)

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return repr(self._get())


class _LiveMapping(Mapping):
    """A read-only name -> value view of the registry that follows :func:`register`."""

    def __init__(self, get: Callable[[], Mapping]):
        self._get = get

    def __getitem__(self, key):
        return self._get()[key]

    def __iter__(self):
        return iter(self._get())

    def __len__(self) -> int:
        return len(self._get())

    def __repr__(self) -> str:
        return repr(dict(self._get()))


#: Every effect's spec, in the order of physics.
EFFECTS: Sequence[EffectSpec] = _LiveSequence(lambda: _snapshot().specs)

#: Effect name -> its spec.
BY_NAME: Mapping[str, EffectSpec] = _LiveMapping(lambda: _snapshot().by_name)

#: The effect names in the order of physics.
EFFECT_NAMES: Sequence[str] = _LiveSequence(lambda: _snapshot().names)

#: The effects the gap diagnosis tries (all of them), in the order of physics.
CANDIDATES: Sequence[Effect] = _LiveSequence(lambda: _snapshot().effects)


def spec(effect: Effect | str) -> EffectSpec:
    """The registry entry of ``effect`` (a name or an :class:`Effect`).

    Raises
    ------
    EffectParamError
        Unknown name (the message lists the valid ones).
    """
    name = effect.value if isinstance(effect, Effect) else str(effect)
    try:
        return _snapshot().by_name[name]
    except KeyError:
        raise EffectParamError(f"effect name {name!r} is unknown; valid: "
                               f"{', '.join(_snapshot().names)}") from None


def params_type(effect: Effect | str) -> type[EffectParams]:
    """The parameter dataclass of ``effect`` (what a twin file's entry becomes)."""
    return spec(effect).source.params_type


def form(effect: Effect | str) -> FittedForm:
    """The gap diagnosis's fitted form of ``effect``."""
    return spec(effect).source.form


def words(effect: Effect | str) -> str:
    """Plain words for ``effect`` (the gap report's sentence); the name if it has none,
    or if it is not registered."""
    try:
        w = params_type(effect).words
    except EffectParamError:
        w = None
    return w if w is not None else str(effect)


#: Effect name -> its plain words, in the order of physics.
WORDS: Mapping[str, str] = _LiveMapping(lambda: {n: words(n) for n in _snapshot().names})


def check_param(effect: Effect | str, name: str, value) -> float:
    """``value`` as a float if the registry's bounds allow it for ``effect.name``.

    Raises
    ------
    EffectParamError
        Not a number, not finite or out of bounds; the message says what is valid.
    """
    s = spec(effect)
    return s.param(name).checked(s.name, value)


# -- adding at run time ----------------------------------------------------------------

def register(definition: EffectDefinition, *, before: str | None = None) -> Effect:
    """Add an effect (a module's ``EFFECT``) to the registry, at the end of the order of
    physics or before the effect called ``before``; returns its name.

    Raises
    ------
    EffectParamError
        The name is taken, or ``before`` is unknown.
    """
    if definition.name in _snapshot().by_name or definition.name == "none":
        raise EffectParamError(f"effect name {definition.name!r} is already registered")
    names = [d.name for d in _REGISTRY]
    if before is not None and before not in names:
        raise EffectParamError(f"effect name {before!r} is unknown; valid: {', '.join(names)}")
    _REGISTRY.insert(names.index(before) if before is not None else len(names), definition)
    _bump()
    return Effect(definition.name)


def unregister(name: str) -> None:
    """Remove an effect added by :func:`register` (the built-in ones stay)."""
    if name in {m.EFFECT.name for m in EFFECT_MODULES}:
        raise EffectParamError(f"effect {name} is built in (EFFECT_MODULES); it stays")
    _REGISTRY[:] = [d for d in _REGISTRY if d.name != name]
    Effect._interned.pop(name, None)
    _bump()


# -- the effects composed at the chain's slots --------------------------------------------

@dataclass(frozen=True)
class Chain:
    """A participant's effects composed at the chain's slots (:data:`SLOTS`): what the
    simulator and the FMU's reference step run.

    Attributes
    ----------
    effects : tuple of EffectParams
        The effects, in the order of physics.
    lag_s : float
        The activation's first-order lag (0: none).
    flexor_ratios : (float, float)
        The flexor path's (wn, zeta) multipliers.
    two_paths : bool
        An effect acts on the flexor path (even with ratios 1).
    delay_s : float
        The force's delay.
    """

    effects: tuple[EffectParams, ...]
    lag_s: float
    flexor_ratios: tuple[float, float]
    two_paths: bool
    delay_s: float

    def acting(self, slot: str) -> tuple[EffectParams, ...]:
        """The effects that act at ``slot``, in the order of physics."""
        return tuple(e for e in self.effects if slot in e.slots)

    @property
    def maps_intensity(self) -> bool:
        return bool(self.acting("intensity"))

    def h(self, intensity):
        """Each muscle's activation of its normalised intensity (composed maps)."""
        x = intensity
        for e in self.acting("intensity"):
            x = e.h(x)
        return x

    @property
    def has_gain(self) -> bool:
        return bool(self.acting("gain"))

    def gain(self, cumulative_stim_s):
        """The force's gain at cumulative stimulation (product of the gain laws; 1
        without one)."""
        gains = self.acting("gain")
        if not gains:
            return np.ones_like(np.asarray(cumulative_stim_s, dtype=float)) \
                if np.ndim(cumulative_stim_s) else 1.0
        g = gains[0].gain(cumulative_stim_s)
        for e in gains[1:]:
            g = g * e.gain(cumulative_stim_s)
        return g

    def additive(self, seed: int) -> Callable[[np.ndarray], np.ndarray] | None:
        """``b(t_s)``: the sum of the additive terms (None without one)."""
        parts = [b for b in (e.additive(seed) for e in self.acting("additive")) if b is not None]
        if not parts:
            return None
        if len(parts) == 1:
            return parts[0]
        return lambda t: sum((b(t) for b in parts[1:]), parts[0](t))


@functools.lru_cache(maxsize=256)
def _chain(effects: tuple[EffectParams, ...]) -> Chain:
    order = {n: i for i, n in enumerate(_snapshot().names)}
    ordered = tuple(sorted(effects, key=lambda e: order.get(e.name, len(order))))
    lags = [e for e in ordered if "lag" in e.slots]
    if len(lags) > 1:
        raise EffectParamError(f"effects {', '.join(e.name for e in lags)} all act on the "
                               "activation lag; the chain has one lag: give one of them")
    rw, rz = 1.0, 1.0
    for e in ordered:
        if "flexor" in e.slots:
            a, b = e.flexor_ratios()
            rw, rz = rw * a, rz * b
    delay = 0.0
    for e in ordered:
        if "delay" in e.slots:
            delay += e.delay_s()
    return Chain(ordered, lags[0].lag_s() if lags else 0.0, (rw, rz),
                 any("flexor" in e.slots for e in ordered), delay)


def chain_of(effects: Iterable[EffectParams]) -> Chain:
    """The effects composed at the chain's slots (in the registry's order of physics).

    Raises
    ------
    EffectParamError
        More than one effect acts on the activation lag.
    """
    return _chain(tuple(effects))


__all__ = ["Effect", "EffectSpec", "ParamSpec", "EffectParamError", "EffectParams",
           "FittedForm", "EffectDefinition", "SLOTS", "EFFECT_MODULES", "EFFECTS", "BY_NAME",
           "EFFECT_NAMES", "CANDIDATES", "WORDS", "spec", "params_type", "form", "words",
           "check_param",
           "register", "unregister", "Chain", "chain_of"]
