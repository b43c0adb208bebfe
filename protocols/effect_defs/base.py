"""What an effect module declares: its parameters, where it acts in the force chain, and
the form the gap diagnosis fits.

The nominal model is one chain (``docs/twin-file.md``): each muscle's normalised intensity
(``I_e = rE sE``, ``I_f = (1 - rE) sE``) -> activation -> second-order dynamics per muscle
path -> net force -> delay -> gain -> plus a baseline. An effect acts at one or more
*slots* of that chain (:data:`SLOTS`), each a pure function of its parameters:

============= ======================================= ==================================
slot          the effect's function                   composed over effects as
============= ======================================= ==================================
``intensity`` ``h(I)``: each muscle's activation      ``h2(h1(I))`` in registry order
``lag``       ``lag_s()``: a first-order lag of the   at most one effect
              activation, ``1 / (lag_s s + 1)``
``flexor``    ``flexor_ratios()``: the flexor path's  products
              ``(wn, zeta)`` multipliers
``delay``     ``delay_s()``: the force answers late   sum
``gain``      ``gain(c_s)`` of cumulative             product
              stimulation ``c_s``
``additive``  ``additive(seed)``: a force ``b(t_s)``  sum
              added to the output
============= ======================================= ==================================

The simulator (:mod:`nmsid.sim_backends.simulation`), the FMU's reference step
(:mod:`nmsid.export.fmu.reference`) and the gap diagnosis (:mod:`nmsid.analysis.gap.models`)
are loops over the registry that compose these functions; none names an effect.

An effect module holds (see ``dead_time.py`` for the smallest one):

- a frozen dataclass subclassing :class:`EffectParams`: one field per parameter declared
  with :func:`param` (meaning, unit in the name, bounds), the class attributes ``name``,
  ``summary``, ``definition``, ``slots`` (and ``words`` for the report), and its slot
  functions;
- a :class:`FittedForm` subclass: the gap fit's parameter vector ``q`` <-> physical values,
  bounds, starting grid, the same slots as functions of ``q``, the twin file's parameters
  and its signature in the data;
- ``EFFECT = EffectDefinition(TheParams, TheForm())``: what the registry lists.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from nmsid.errors import UserError

#: The chain's slots, in the order of physics.
SLOTS: tuple[str, ...] = ("intensity", "lag", "flexor", "delay", "gain", "additive")


class EffectParamError(UserError, ValueError):
    """A value of an effect parameter is outside what the registry allows.

    The message names the parameter (``effect.param``), the value and the valid range; the
    simulator re-raises it as its own configuration error.
    """


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

    def checked(self, effect: str, value: Any) -> float:
        """``value`` as a float if the bounds allow it (:class:`EffectParamError` naming
        ``effect.name``, the value and the range otherwise)."""
        label = f"{effect}.{self.name}"
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise EffectParamError(f"{label} must be a number, got {value!r}") from None
        if not self.contains(v):
            raise EffectParamError(f"{label} must be a finite number {self.bounds_text()}, "
                                   f"got {value!r}")
        return v


def param(meaning: str, lower: float | None = None, upper: float | None = None, *,
          lower_open: bool = False, choices: type[enum.Enum] | None = None,
          required: bool = True, default: float | None = None) -> Any:
    """A parameter field of an :class:`EffectParams` dataclass (its :class:`ParamSpec`
    is made from the field's name and these arguments).

    ``choices``: an Enum of the valid values (a shape); ``required=False`` without
    ``default``: the field defaults to None (a parameter only some shapes need).
    """
    meta = {"meaning": meaning, "lower": lower, "upper": upper, "lower_open": lower_open,
            "choices": choices, "required": required and default is None,
            "default": default}
    if required and default is None:
        return dataclasses.field(metadata={"param": meta})
    return dataclasses.field(default=default, metadata={"param": meta})


def _spec_of(f: dataclasses.Field) -> ParamSpec:
    m = f.metadata["param"]
    choices = tuple(c.value for c in m["choices"]) if m["choices"] is not None else ()
    return ParamSpec(f.name, m["meaning"], m["lower"], m["upper"], m["lower_open"],
                     choices, m["required"], m["default"])


class EffectParams:
    """Base of an effect's parameter dataclass (subclasses are frozen dataclasses).

    Construction checks every given parameter against its :class:`ParamSpec`
    (:class:`EffectParamError` otherwise) and turns shape strings into their Enum. The slot
    functions below are neutral; an effect overrides those of its :attr:`slots`.
    """

    name: ClassVar[str]
    summary: ClassVar[str]
    definition: ClassVar[str]
    slots: ClassVar[frozenset[str]] = frozenset()
    #: Plain words for the gap report's sentence ("the gap is explained by <words>");
    #: None: the name.
    words: ClassVar[str | None] = None
    #: Effects whose footprint in the data resembles this one's (their names): the gap
    #: report sets each such pair's scores side by side. Declare a pair in one of the two.
    confusable_with: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def param_specs(cls) -> tuple[ParamSpec, ...]:
        """The parameters' specs, in field order."""
        return tuple(_spec_of(f) for f in dataclasses.fields(cls)  # type: ignore[arg-type]
                     if "param" in f.metadata)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            choices = f.metadata["param"]["choices"]
            v = getattr(self, f.name)
            if choices is not None:
                try:
                    v = choices(getattr(v, "value", v))
                except ValueError:
                    raise EffectParamError(
                        f"{self.name}.{f.name} {v!r} is unknown; valid: "
                        f"{', '.join(c.value for c in choices)}") from None
                object.__setattr__(self, f.name, v)
        for n in self.checked_names():
            spec = _spec_of(next(f for f in dataclasses.fields(self)  # type: ignore[arg-type]
                                 if f.name == n))
            object.__setattr__(self, n, spec.checked(self.name, getattr(self, n)))

    def checked_names(self) -> tuple[str, ...]:
        """The numeric parameters to check (default: every one that is given)."""
        return tuple(f.name for f in dataclasses.fields(self)  # type: ignore[arg-type]
                     if f.metadata["param"]["choices"] is None
                     and getattr(self, f.name) is not None)

    def params(self) -> dict[str, Any]:
        """The twin file's ``params`` object (shapes as their names; unset ones left out)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if v is not None:
                out[f.name] = v.value if isinstance(v, enum.Enum) else v
        return out

    # -- the slot functions (neutral here) -------------------------------------------------
    def h(self, intensity: Any) -> Any:
        """``intensity`` slot: activation of normalised intensity (array)."""
        return np.asarray(intensity, dtype=float)

    def lag_s(self) -> float:
        """``lag`` slot: the activation's first-order time constant, s (0: none)."""
        return 0.0

    def flexor_ratios(self) -> tuple[float, float]:
        """``flexor`` slot: the flexor path's (wn, zeta) multipliers."""
        return 1.0, 1.0

    def delay_s(self) -> float:
        """``delay`` slot: the force's delay, s."""
        return 0.0

    def gain(self, cumulative_stim_s: Any) -> Any:
        """``gain`` slot: the force's gain at cumulative stimulation ``c`` s."""
        return np.ones_like(np.asarray(cumulative_stim_s, dtype=float))

    def additive(self, seed: int) -> Callable[[np.ndarray], np.ndarray] | None:
        """``additive`` slot: ``b(t_s)`` in N added to the force (None: nothing), drawn
        from the participant's ``seed``."""
        return None


class FittedForm:
    """The gap diagnosis's form of one effect: what the fit, the report and the twin file
    need of it. ``q`` is the effect's part of the solver's unconstrained parameter vector.

    Attributes
    ----------
    n : int
        Number of shared (all-sE) parameters the solver fits.
    bounds : tuple of (float, float)
        Their bounds on the solver's unconstrained scale.
    through_nuisance : bool
        The effect acts through the per-trial nuisance basis (a slow baseline): no solver
        parameter; its bandwidth is chosen on a grid.
    knots : numpy.ndarray or None
        ``intensity`` slot only: the fitted curve is a monotone cubic (PCHIP) through
        :meth:`knot_values` at these intensities (the fit then evaluates it through a
        precomputed linear basis); None: :meth:`fit_curve` is evaluated directly.
    """

    n: ClassVar[int] = 1
    bounds: ClassVar[tuple[tuple[float, float], ...]] = ()
    through_nuisance: ClassVar[bool] = False
    knots: ClassVar[np.ndarray | None] = None

    def grid(self) -> list[list[float]]:
        """Starting points screened for the shared parameters."""
        return [[]]

    def physical(self, q: np.ndarray) -> dict[str, float]:
        """Our physical parameters from the solver's ``q``."""
        return {}

    def final(self, p: dict, ctx: Any) -> None:
        """Add the derived figures of the final fit to ``p`` (in place); ``ctx`` has ``q``,
        ``sE_levels`` and ``drift_amplitude()`` (``analysis.gap.models.FinalContext``)."""

    def twin_params(self, p: Mapping[str, float], sE_levels: Any) -> dict:
        """The twin file's ``params`` of the effect (the registry's names)."""
        raise NotImplementedError

    def signature(self, sig: Any) -> str:
        """One line: the signature in the data that points at this effect (``sig``:
        ``analysis.gap.evidence.Signatures``)."""
        raise NotImplementedError

    def pair_evidence(self, other: str, sig: Any) -> dict | None:
        """Figures that tell this effect from a confusable one (``other``: its name) in the
        signatures ``sig``, added to the report's pair; None (the default): the two
        candidates' scores say it alone."""
        return None

    # -- the slots as functions of q -------------------------------------------------------
    def fit_curve(self, q: np.ndarray) -> Callable[[Any], Any]:
        """``intensity``: the fitted ``h(I)``."""
        raise NotImplementedError

    def knot_values(self, q: np.ndarray) -> np.ndarray:
        """``intensity`` with :attr:`knots`: the curve's values at the knots."""
        raise NotImplementedError

    def fit_lag_s(self, q: np.ndarray) -> float:
        """``lag``: the time constant, s."""
        raise NotImplementedError

    def fit_flexor_ratios(self, q: np.ndarray) -> tuple[float, float]:
        """``flexor``: (wn, zeta) multipliers of the flexor path."""
        raise NotImplementedError

    def fit_delay_s(self, q: np.ndarray) -> float:
        """``delay``: the delay, s."""
        raise NotImplementedError

    def fit_gain(self, q: np.ndarray, cumulative_stim_s: np.ndarray) -> np.ndarray:
        """``gain``: the gain at cumulative stimulation (any shape of array)."""
        raise NotImplementedError


@dataclass(frozen=True)
class EffectDefinition:
    """An effect module's one export, what the registry lists.

    Attributes
    ----------
    params_type : type
        The :class:`EffectParams` dataclass (name, parameters, slots, the physics).
    form : FittedForm
        What the gap diagnosis fits.
    """

    params_type: type[EffectParams]
    form: FittedForm

    def __post_init__(self) -> None:
        t = self.params_type
        unknown = set(t.slots) - set(SLOTS)
        if unknown or not dataclasses.is_dataclass(t):
            raise TypeError(f"effect {t.__name__}: must be a dataclass acting on slots among "
                            f"{SLOTS}, got {sorted(unknown)}")
        bare = [f.name for f in dataclasses.fields(t) if "param" not in f.metadata]
        if bare:
            raise TypeError(f"effect {t.__name__}: fields {bare} are not declared with "
                            "param() (class attributes need ClassVar, imported at the "
                            "module's top)")

    @property
    def name(self) -> str:
        return self.params_type.name

    @property
    def slots(self) -> frozenset[str]:
        return self.params_type.slots


__all__ = ["SLOTS", "EffectParamError", "ParamSpec", "param", "EffectParams", "FittedForm",
           "EffectDefinition"]
