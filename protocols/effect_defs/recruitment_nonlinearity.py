"""Recruitment nonlinearity: each muscle's activation is a monotone, non-linear function
``h`` of its normalised intensity (slot ``intensity``).

``a_e = h(I_e)``, ``a_f = h(I_f)`` with ``h(0) = 0``, ``h(1) = 1`` (unit slope outside
[0, 1]); net drive ``(h(I_e) - h(I_f)) / (2 sE)``. The twin file names a family (power,
sigmoid, threshold_saturation); the fit uses a family-free curve: a monotone cubic through
knots at I = 0, 0.1, 0.25, ..., 0.85, 1 (five free increments), a cumulative distribution
of motor-unit thresholds that can be convex, concave, S-shaped or have a threshold and a
saturation, projected on the families when written out.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import (
    EffectDefinition,
    EffectParamError,
    EffectParams,
    FittedForm,
    param,
)


class RecruitmentShape(enum.Enum):
    POWER = "power"
    SIGMOID = "sigmoid"
    THRESHOLD_SATURATION = "threshold_saturation"


_SHAPE_PARAMS = {RecruitmentShape.POWER: ("gamma",),
                 RecruitmentShape.SIGMOID: ("slope", "midpoint"),
                 RecruitmentShape.THRESHOLD_SATURATION: ("threshold", "saturation")}


def _logistic(z):
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(z, dtype=float)))


@dataclass(frozen=True)
class RecruitmentNonlinearity(EffectParams):
    """Each muscle's normalised intensity I in [0, 1] becomes activation h(I), h(0)=0,
    h(1)=1 (outside [0, 1] h continues with unit slope).

    power: ``I ** gamma``; sigmoid: a logistic of ``slope (I - midpoint)`` rescaled to
    pass through (0, 0) and (1, 1); threshold_saturation: ``clip((I - threshold) /
    (saturation - threshold), 0, 1)``.
    """

    shape: RecruitmentShape = param(
        "the curve's family", choices=RecruitmentShape)
    gamma: float | None = param("power: the exponent", 0.0, 10.0, lower_open=True,
                                required=False)
    slope: float | None = param("sigmoid: steepness per unit intensity", 0.0, 200.0,
                                lower_open=True, required=False)
    midpoint: float | None = param("sigmoid: intensity at half rise", required=False)
    threshold: float | None = param("threshold_saturation: intensity where force begins",
                                    0.0, 1.0, required=False)
    saturation: float | None = param(
        "threshold_saturation: intensity where force stops rising", 0.0, 1.0, required=False)

    name: ClassVar[str] = "recruitment_nonlinearity"
    summary: ClassVar[str] = ("each muscle's activation is a monotone, non-linear function of "
                              "its intensity")
    definition: ClassVar[str] = (
        "a_e = h(I_e), a_f = h(I_f) with h(0) = 0, h(1) = 1 on the normalised intensity "
        "(unit slope outside [0, 1]); net drive (h(I_e) - h(I_f)) / (2 sE). "
        "power: h = I^gamma; sigmoid: logistic(slope (I - midpoint)) rescaled through (0, 0) "
        "and (1, 1); threshold_saturation: clip((I - threshold) / (saturation - threshold), "
        "0, 1)")
    slots: ClassVar[frozenset[str]] = frozenset({"intensity"})
    words: ClassVar[str | None] = "non-linear motor-unit recruitment"
    confusable_with: ClassVar[tuple[str, ...]] = ("flexor_extensor_asymmetry",)

    def __post_init__(self) -> None:
        super().__post_init__()
        th, sat = self.threshold, self.saturation
        if self.shape is RecruitmentShape.THRESHOLD_SATURATION and not (
                th is not None and sat is not None and th < sat):
            raise EffectParamError(
                "recruitment_nonlinearity needs 0 <= threshold < saturation <= 1, got "
                f"threshold={th!r}, saturation={sat!r}")

    def checked_names(self) -> tuple[str, ...]:
        shape = RecruitmentShape(self.shape)
        for p in _SHAPE_PARAMS[shape]:
            if getattr(self, p) is None:
                raise EffectParamError(
                    f"recruitment_nonlinearity with shape {shape.value} needs "
                    f"{', '.join(_SHAPE_PARAMS[shape])}; {p} missing")
        return _SHAPE_PARAMS[shape]

    def params(self) -> dict[str, Any]:
        d: dict[str, Any] = {"shape": self.shape.value}
        d.update({p: getattr(self, p) for p in _SHAPE_PARAMS[self.shape]})
        return d

    def h(self, intensity):
        """Activation of normalised intensity (array); unit slope outside [0, 1]."""
        x = np.asarray(intensity, dtype=float)
        xin = np.clip(x, 0.0, 1.0)
        if self.shape is RecruitmentShape.POWER:
            y = xin ** self.gamma
        elif self.shape is RecruitmentShape.SIGMOID:
            slope, mid = float(self.slope), float(self.midpoint)  # type: ignore[arg-type]
            lo = _logistic(-slope * mid)
            hi = _logistic(slope * (1.0 - mid))
            y = (_logistic(slope * (xin - mid)) - lo) / (hi - lo)
        else:
            th, sat = float(self.threshold), float(self.saturation)  # type: ignore[arg-type]
            y = np.clip((xin - th) / (sat - th), 0, 1)
        return y + (x - xin)


# -- the fitted form ---------------------------------------------------------------------

#: Knots of our recruitment curve (normalised intensity).
RECRUITMENT_KNOTS = np.array([0.0, 0.1, 0.25, 0.45, 0.65, 0.85, 1.0])


def recruitment_knot_values(q: np.ndarray) -> np.ndarray:
    """Curve values at :data:`RECRUITMENT_KNOTS` from the unconstrained parameters ``q``
    (one per knot increment but the first): increments ``dk_i exp(z_i)`` normalised to sum
    to 1 with ``z = [0, q]``, so the curve rises monotonically from 0 to 1; ``q = 0`` is the
    identity."""
    z = np.concatenate([[0.0], np.asarray(q, float)])
    w = np.diff(RECRUITMENT_KNOTS) * np.exp(z - z.max())
    w /= w.sum()
    return np.concatenate([[0.0], np.cumsum(w)])


def _recruitment_start(h) -> list[float]:
    """``q`` of the knot curve through a given shape (for the starting grid)."""
    inc = np.maximum(np.diff(h(RECRUITMENT_KNOTS)), 1e-4) / np.diff(RECRUITMENT_KNOTS)
    z = np.clip(np.log(inc / inc[0]), -4.0, 4.0)
    return z[1:].tolist()


def _recruitment_grid() -> list[list[float]]:
    """Identity, convex, concave and S-shaped starts (generic shapes, not any simulator's)."""
    shapes = [lambda I: I, lambda I: I ** 2, lambda I: np.sqrt(I),
              lambda I: 3 * I ** 2 - 2 * I ** 3,
              lambda I: np.clip((I - 0.1) / 0.7, 0, 1) * 0.98 + 0.02 * I,
              lambda I: 1 - (1 - I) ** 2]
    return [_recruitment_start(h) for h in shapes]


def recruitment_curve(q: np.ndarray):
    """Our recruitment curve ``h(I)``: a monotone cubic (PCHIP) through the knot values,
    identity-slope continuation outside [0, 1]."""
    from scipy.interpolate import PchipInterpolator
    f = PchipInterpolator(RECRUITMENT_KNOTS, recruitment_knot_values(q))

    def h(I):
        x = np.asarray(I, float)
        xin = np.clip(x, 0.0, 1.0)
        return f(xin) + (x - xin)
    return h


def net_static_map(h, sE_levels, n_d: int = 41) -> np.ndarray:
    """(n_levels, n_d) normalised net drive ``(h(I_e) - h(I_f)) / (2 sE)`` over
    ``d = rE - 0.5`` in [-0.5, 0.5], each row scaled to unit least-squares slope (the
    per-sE gain is free, so only the shape is identifiable)."""
    d = np.linspace(-0.5, 0.5, n_d)
    rows = []
    for sE in np.atleast_1d(sE_levels):
        x = (h((0.5 + d) * sE) - h((0.5 - d) * sE)) / (2 * sE)
        slope = float(x @ d / (d @ d))
        rows.append(x / slope if slope != 0 else x)
    return np.array(rows)


def nonlinearity_index_pct(h, sE_levels) -> float:
    """RMS departure of the normalised net static map from a straight line, in % of the
    drive's range (0 for linear recruitment): the recruitment effect's size that a chirp
    at constant sE can see, independent of the curve's family."""
    m = net_static_map(h, sE_levels)
    d = np.linspace(-0.5, 0.5, m.shape[1])
    return float(100.0 * np.sqrt(np.mean((m - d[None, :]) ** 2)))


def project_recruitment(h, sE_levels) -> dict:
    """The twin file's shape parameters whose net static map is closest to our curve ``h``."""
    from scipy import optimize  # only when a recruitment effect is written out
    target = net_static_map(h, sE_levels)
    best, best_cost = None, np.inf
    trials = [
        ("power", ["gamma"], [[0.5], [1.5], [2.5], [3.5]], [(0.1, 10.0)]),
        ("sigmoid", ["slope", "midpoint"], [[4, 0.5], [8, 0.4], [12, 0.6], [6, 0.3]],
         [(0.5, 100.0), (-0.5, 1.5)]),
        ("threshold_saturation", ["threshold", "saturation"],
         [[0.05, 0.9], [0.1, 0.7], [0.2, 1.0], [0.0, 0.6]], [(0.0, 0.9), (0.1, 1.0)]),
    ]
    for shape, names, starts, bounds in trials:
        def cost(v, shape=shape, names=names):
            params = {"shape": shape, **dict(zip(names, (float(x) for x in v), strict=True))}
            try:
                m = net_static_map(RecruitmentNonlinearity(**params).h, sE_levels)
            except Exception:  # an invalid combination (e.g. threshold >= saturation)
                return 1e6
            return float(np.sum((m - target) ** 2))
        for s0 in starts:
            r = optimize.minimize(cost, s0, method="Nelder-Mead",
                                  options={"xatol": 1e-4, "fatol": 1e-10, "maxiter": 400})
            lo = np.array([bd[0] for bd in bounds])
            hi = np.array([bd[1] for bd in bounds])
            v = np.clip(r.x, lo, hi)
            c = cost(v)
            if c < best_cost:
                best_cost = c
                best = {"shape": shape, **dict(zip(names, (float(x) for x in v), strict=True))}
    return best or {}


class RecruitmentForm(FittedForm):
    """Our knot curve (:func:`recruitment_curve`); ``q``: log increments of the knots."""

    n = len(RECRUITMENT_KNOTS) - 2
    bounds = ((-4.0, 4.0),) * (len(RECRUITMENT_KNOTS) - 2)
    knots = RECRUITMENT_KNOTS

    def grid(self):
        return _recruitment_grid()

    def physical(self, q):
        return {f"h_{k:.2f}": float(v) for k, v in
                zip(RECRUITMENT_KNOTS[1:-1], recruitment_knot_values(q)[1:-1], strict=True)}

    def fit_curve(self, q):
        return recruitment_curve(q)

    def knot_values(self, q):
        return recruitment_knot_values(q)

    def final(self, p, ctx):
        h = recruitment_curve(ctx.q)
        p["nonlinearity_index_pct"] = nonlinearity_index_pct(h, ctx.sE_levels)
        p["_curve"] = h

    def twin_params(self, p, sE_levels):
        return project_recruitment(p["_curve"], sE_levels)

    def signature(self, sig):
        hm = sig.harmonics
        return (f"signature: residual 3f harmonic {hm['median_3f_pct']:.2f} % and 2f "
                f"{hm['median_2f_pct']:.2f} % of the fundamental against "
                f"{hm['median_1.5f_noise_reference_pct']:.2f} % at the non-harmonic 1.5f.")


EFFECT = EffectDefinition(RecruitmentNonlinearity, RecruitmentForm())
