"""Parameter curves of sE, in the twin file's families (``docs/twin-file.md``).

Examples
--------
>>> c = ParameterCurve(CurveModel.QUADRATIC, (10.0, 40.0, -25.0))
>>> round(c(0.8), 6)
26.0
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from nmsid.sim_backends.errors import SimConfigError


class CurveModel(enum.Enum):
    """A curve family; the value is its name in ``twin.json``."""

    CONSTANT = "constant"
    LINEAR = "linear"
    QUADRATIC = "quadratic"
    EXPONENTIAL = "exponential"

    @property
    def n_coefficients(self) -> int:
        return {"constant": 1, "linear": 2, "quadratic": 3, "exponential": 2}[self.value]


def curve_values(model: CurveModel, coefficients, sE) -> np.ndarray:
    """The one evaluation of a twin-file curve family at ``sE`` (array in, array out);
    the analysis's :func:`nmsid.analysis.curves.evaluate_curve` uses it too."""
    s = np.asarray(sE, dtype=float)
    c = [float(v) for v in coefficients]
    if model is CurveModel.CONSTANT:
        return np.full_like(s, c[0])
    if model is CurveModel.LINEAR:
        return c[0] + c[1] * s
    if model is CurveModel.QUADRATIC:
        return c[0] + c[1] * s + c[2] * s * s
    return c[0] * np.exp(c[1] * s)


@dataclass(frozen=True)
class ParameterCurve:
    """A parameter as a function of sE.

    ``constant``: ``a``; ``linear``: ``a + b sE``; ``quadratic``: ``a + b sE + c sE^2``;
    ``exponential``: ``a exp(b sE)`` (coefficients in this order).
    """

    model: CurveModel
    coefficients: tuple[float, ...]

    def __post_init__(self):
        model = self.model
        if not isinstance(model, CurveModel):
            try:
                model = CurveModel(str(model))
            except ValueError:
                raise SimConfigError(
                    f"curve model {self.model!r} is unknown; valid: "
                    f"{', '.join(m.value for m in CurveModel)}") from None
            object.__setattr__(self, "model", model)
        coeffs = tuple(float(c) for c in self.coefficients)
        if len(coeffs) != model.n_coefficients:
            raise SimConfigError(
                f"a {model.value} curve needs {model.n_coefficients} coefficients, got "
                f"{len(coeffs)}: {list(coeffs)}")
        if not all(math.isfinite(c) for c in coeffs):
            raise SimConfigError(f"curve coefficients must be finite, got {list(coeffs)}")
        object.__setattr__(self, "coefficients", coeffs)

    def __call__(self, sE):
        out = curve_values(self.model, self.coefficients, sE)
        return float(out) if np.ndim(out) == 0 else out

    def to_dict(self) -> dict:
        """The twin-file form ``{"model": ..., "coefficients": [...]}``."""
        return {"model": self.model.value, "coefficients": list(self.coefficients)}

    @classmethod
    def from_dict(cls, d: dict, name: str = "curve") -> ParameterCurve:
        """Parse the twin-file form; errors name ``name``."""
        if not isinstance(d, dict) or "model" not in d or "coefficients" not in d:
            raise SimConfigError(f"{name} must be an object with 'model' and "
                                 f"'coefficients', got {d!r}")
        try:
            return cls(d["model"], tuple(d["coefficients"]))
        except SimConfigError as exc:
            raise SimConfigError(f"{name}: {exc}") from None
        except TypeError:
            raise SimConfigError(f"{name}: coefficients must be a list of numbers, got "
                                 f"{d['coefficients']!r}") from None

    @classmethod
    def constant(cls, value: float) -> ParameterCurve:
        return cls(CurveModel.CONSTANT, (value,))
