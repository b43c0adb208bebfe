"""A fitted model's named parameters: one read-only mapping type for gap and muscle fits.

:class:`Parameters` is what ``ModelFit.params`` (:mod:`nmsid.analysis.gap.fit`),
``Candidate.params`` (:mod:`nmsid.analysis.gap.models`) and ``MuscleFit.params``
(:mod:`nmsid.analysis.muscle.fit`) return: name -> value in the fit's own units (the unit
is in the name: ``L_s``, ``tau_act_s``, ``corner_Hz``), read like a dict, never changed in
place (a caller that adjusts values copies first: ``dict(p)`` or :meth:`Parameters.to_dict`).

Examples
--------
>>> p = Parameters.of({"L_s": 0.02, "timing_correction_s": 0.0})
>>> p["L_s"], len(p), "L_s" in p
(0.02, 2, True)
>>> p.to_dict()
{'L_s': 0.02, 'timing_correction_s': 0.0}
>>> p["L_s"] = 0.03
Traceback (most recent call last):
...
TypeError: 'Parameters' object does not support item assignment
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass


@dataclass(frozen=True, eq=False)   # Mapping's ==: equal to a dict of the same items
class Parameters(Mapping[str, float]):
    """Named parameter values of a fitted model, read-only and in their fit's order.

    Compares equal to any mapping with the same items (``p == {"L_s": 0.02}``).

    Attributes
    ----------
    items_ : tuple of (str, float)
        The (name, value) pairs, names unique (build with :meth:`of`).
    """

    items_: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        names = [k for k, _ in self.items_]
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names repeat: {names}")

    @classmethod
    def of(cls, values: Mapping[str, float]) -> Parameters:
        """From a mapping name -> value (values as float)."""
        return cls(tuple((str(k), float(v)) for k, v in values.items()))

    def __getitem__(self, name: str) -> float:
        for k, v in self.items_:
            if k == name:
                return v
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return (k for k, _ in self.items_)

    def __len__(self) -> int:
        return len(self.items_)

    def to_dict(self) -> dict[str, float]:
        """A plain (mutable) copy, name -> value, for JSON or for adjusting."""
        return dict(self.items_)
