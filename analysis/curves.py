"""The three curves of a parameter against sE, their least-squares fits, AICc and trend.

* linear ``a + b sE``, quadratic ``a + b sE + c sE^2``: ordinary least squares;
* exponential ``a exp(b sE)``: non-linear least squares on the raw scale. For fixed b the
  best a is linear (a = sum y e^{b x} / sum e^{2 b x}), so the fit is a one-dimensional
  search over b (variable projection): a log-linear fit gives the start when the data
  have one sign, a grid over b brackets the minimum otherwise (negative and mixed-sign data
  work: a takes the sign of the data), then Newton steps on the exact derivatives polish it.

AICc = n ln(RSS / n) + 2k + 2k(k + 1) / (n - k - 1), with k the number of coefficients
(+1 when the noise variance is counted, a setting). When n - k - 1 <= 0 the correction is
undefined and the model is not selectable; the comparison says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nmsid.sim_backends.curves import CurveModel, curve_values

N_COEFFICIENTS = {"linear": 2, "quadratic": 3, "exponential": 2}


def evaluate_curve(model: str, coefficients, sE) -> np.ndarray:
    """Value of a curve (``linear``, ``quadratic``, ``exponential``, ``constant``) at sE."""
    try:
        family = CurveModel(model)
    except ValueError:
        raise ValueError(f"unknown curve model {model!r}: use linear, quadratic, exponential "
                         "or constant") from None
    return curve_values(family, coefficients, sE)


def aicc(n: int, rss: float, k: int) -> float | None:
    """Corrected Akaike information criterion; None when n - k - 1 <= 0.

    Examples
    --------
    >>> round(aicc(15, 2.0, 2), 4)    # 15 ln(2/15) + 2*2 + 2*2*3/(15-2-1)
    -25.2235
    >>> aicc(3, 1.0, 2) is None
    True
    """
    if n - k - 1 <= 0:
        return None
    rss = max(float(rss), 1e-300)
    return n * math.log(rss / n) + 2 * k + 2 * k * (k + 1) / (n - k - 1)


@dataclass
class Trend:
    """The shape of a fitted curve over the tested sE range, in words and numbers."""

    direction: str
    """``increasing``, ``decreasing``, ``constant``, ``decreasing then increasing`` or
    ``increasing then decreasing`` over the tested range."""
    opens: str | None = None
    """Quadratic only: ``up`` (convex, has a minimum) or ``down`` (concave, a maximum)."""
    extremum_sE: float | None = None
    """Quadratic only: where the extremum lies (sE = -b / 2c)."""
    extremum_value: float | None = None
    extremum_inside: bool | None = None
    """Whether the extremum lies inside the tested sE range."""
    text: str = ""


def trend_of(model: str, coefficients, sE_min: float, sE_max: float) -> Trend:
    """Describe a curve's trend over [sE_min, sE_max] without ambiguity.

    Examples
    --------
    >>> print(trend_of("quadratic", [1.0, -2.0, 2.0], 0.3, 1.0).text)
    ... # doctest: +NORMALIZE_WHITESPACE
    decreasing then increasing: opens up (convex), minimum at sE = 0.5
    (inside the tested range 0.3-1)
    """
    c = [float(v) for v in coefficients]
    rng = f"{sE_min:g}-{sE_max:g}"
    if model == "linear" or model == "exponential":
        slope = c[1] if model == "linear" else c[0] * c[1]
        ends = np.abs(evaluate_curve(model, c, [sE_min, sE_max]))
        change = abs(float(np.diff(evaluate_curve(model, c, [sE_min, sE_max]))[0]))
        if change <= 1e-9 * max(float(ends.max()), 1e-300):
            slope = 0.0                      # flat to rounding over the tested range
        direction = "increasing" if slope > 0 else "decreasing" if slope < 0 else "constant"
        text = direction
        if model == "exponential" and slope != 0:
            text += (", ever steeper" if c[1] > 0 else ", levelling off") + \
                f" (rate b = {c[1]:.3g} per unit sE)"
        return Trend(direction=direction, text=text)
    if model == "quadratic":
        a, b, q = c
        if q == 0:
            return trend_of("linear", [a, b], sE_min, sE_max)
        x0 = -b / (2 * q)
        y0 = a + b * x0 + q * x0 * x0
        inside = sE_min < x0 < sE_max
        opens = "up" if q > 0 else "down"
        kind = "minimum" if q > 0 else "maximum"
        if inside:
            direction = "decreasing then increasing" if q > 0 else "increasing then decreasing"
        else:
            slope_mid = b + 2 * q * (sE_min + sE_max) / 2
            direction = "increasing" if slope_mid > 0 else "decreasing"
        where = "inside" if inside else "outside"
        text = (f"{direction}: opens {opens} ({'convex' if q > 0 else 'concave'}), {kind} at "
                f"sE = {x0:.3g} ({where} the tested range {rng})")
        return Trend(direction=direction, opens=opens, extremum_sE=x0, extremum_value=y0,
                     extremum_inside=inside, text=text)
    raise ValueError(f"unknown curve model {model!r}")


@dataclass
class CurveFit:
    """One curve fitted to one set of points."""

    model: str
    coefficients: list[float]
    rss: float
    n: int
    k: int
    """Parameters counted in AICc."""
    aicc: float | None
    notes: list[str] = field(default_factory=list)

    @property
    def selectable(self) -> bool:
        return self.aicc is not None and math.isfinite(self.aicc)

    def predict(self, sE) -> np.ndarray:
        return evaluate_curve(self.model, self.coefficients, sE)


def _polyfit(x: np.ndarray, y: np.ndarray, degree: int) -> list[float]:
    v = np.vander(x, degree + 1, increasing=True)
    return [float(c) for c in np.linalg.lstsq(v, y, rcond=None)[0]]


def _exp_projected(x: np.ndarray, y: np.ndarray, b: float) -> tuple[float, float]:
    e = np.exp(b * x)
    ee = float(e @ e)
    a = float(e @ y) / ee if ee > 0 and np.isfinite(ee) else 0.0
    r = y - a * e
    return a, float(r @ r)


def fit_exponential(x, y) -> tuple[list[float], list[str]]:
    """Least-squares a exp(b x) on the raw scale (see the module docstring).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(0.3, 1.0, 15)
    >>> [round(c, 9) for c in fit_exponential(x, -2.0 * np.exp(1.5 * x))[0]]
    [-2.0, 1.5]
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    notes: list[str] = []
    span = max(float(np.ptp(x)), 1e-12)
    b_max = 50.0 / span                     # e^50 over the range: beyond any data
    starts = []
    if np.all(y > 0) or np.all(y < 0):
        sign = 1.0 if y[0] > 0 else -1.0
        slope = np.polyfit(x, np.log(sign * y), 1)[0]
        starts.append(float(np.clip(slope, -b_max, b_max)))
    grid = np.linspace(-b_max / 5, b_max / 5, 81)
    e = np.exp(np.outer(grid, x))                       # all grid points at once
    a_grid = (e * y).sum(axis=1) / (e * e).sum(axis=1)
    costs = ((y - a_grid[:, None] * e) ** 2).sum(axis=1)
    starts.append(float(grid[int(np.argmin(costs))]))
    best_b, best_cost = starts[0], math.inf      # starts is never empty (the grid's best)
    for b in starts:
        # Newton on the projected cost with numerical derivatives, safeguarded by halving
        cost = _exp_projected(x, y, b)[1]
        step_h = 1e-4 * max(1.0, abs(b))
        for _ in range(100):
            c_plus = _exp_projected(x, y, b + step_h)[1]
            c_minus = _exp_projected(x, y, b - step_h)[1]
            g = (c_plus - c_minus) / (2 * step_h)
            hess = (c_plus - 2 * cost + c_minus) / step_h ** 2
            step = -g / hess if hess > 0 else -math.copysign(0.1 / span, g)
            improved = False
            for _ in range(40):
                nb = float(np.clip(b + step, -b_max, b_max))
                nc = _exp_projected(x, y, nb)[1]
                if nc <= cost:
                    improved = True
                    break
                step /= 2
            if not improved:
                break
            done = abs(nb - b) <= 1e-12 * max(1.0, abs(b)) or cost - nc <= 1e-15 * cost
            b, cost = nb, nc
            step_h = 1e-4 * max(1.0, abs(b)) if abs(step) > 1e-3 else 1e-6 * max(1.0, abs(b))
            if done:
                break
        if cost < best_cost:
            best_b, best_cost = b, cost
    if abs(best_b) >= 0.999 * b_max:
        notes.append(f"exponential rate ran to the search limit |b| = {b_max:.3g}; the data "
                     "do not look exponential")
    a, _ = _exp_projected(x, y, best_b)
    return [a, best_b], notes


def fit_curve(model: str, sE, values, count_noise_variance: bool = False) -> CurveFit:
    """Fit one curve by least squares on the raw scale and compute its AICc.

    Parameters
    ----------
    model : str
        ``linear``, ``quadratic`` or ``exponential``.
    sE, values : array-like
        The points (same length, finite).
    count_noise_variance : bool
        Count the residual variance as a parameter in AICc.
    """
    x = np.asarray(sE, dtype=float)
    y = np.asarray(values, dtype=float)
    n = len(x)
    n_coef = N_COEFFICIENTS[model]
    k = n_coef + (1 if count_noise_variance else 0)
    notes: list[str] = []
    if n < n_coef:
        return CurveFit(model, [], float("nan"), n, k, None,
                        [f"{n} point(s) cannot determine the {n_coef} coefficients of the "
                         f"{model} model"])
    if model == "exponential":
        coef, notes = fit_exponential(x, y)
    else:
        coef = _polyfit(x, y, 1 if model == "linear" else 2)
    r = y - evaluate_curve(model, coef, x)
    rss = float(r @ r)
    value = aicc(n, rss, k)
    if value is None:
        notes.append(f"AICc undefined: n - k - 1 = {n} - {k} - 1 <= 0 (needs at least "
                     f"{k + 2} points); not selectable")
    return CurveFit(model, coef, rss, n, k, value, notes)
