"""Flexor/extensor asymmetry: the flexor's dynamics have ``wn x wn_ratio`` and
``zeta x zeta_ratio`` (slot ``flexor``), so ``F = Kp (G_e(s) u_e - G_f(s) u_f)``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param


@dataclass(frozen=True)
class FlexorExtensorAsymmetry(EffectParams):
    """The flexor's dynamics have wn x ``wn_ratio`` and zeta x ``zeta_ratio``; the
    extensor keeps the nominal ones."""

    wn_ratio: float = param("flexor wn / extensor wn", 0.0, 10.0, lower_open=True)
    zeta_ratio: float = param("flexor zeta / extensor zeta", 0.0, 10.0, lower_open=True)

    name: ClassVar[str] = "flexor_extensor_asymmetry"
    summary: ClassVar[str] = "the flexor's dynamics differ from the extensor's"
    definition: ClassVar[str] = ("F = Kp (G_e(s) u_e - G_f(s) u_f) with G_e = G(wn, zeta) and "
                                 "G_f = G(wn wn_ratio, zeta zeta_ratio)")
    slots: ClassVar[frozenset[str]] = frozenset({"flexor"})
    words: ClassVar[str | None] = "different dynamics of flexor and extensor"

    def flexor_ratios(self) -> tuple[float, float]:
        return self.wn_ratio, self.zeta_ratio


def canonical_asymmetry(wn_ratio: float, zeta_ratio: float) -> tuple[float, float, bool]:
    """Orientation convention for the asymmetry ratios.

    With linear recruitment the net response to ``rE - 0.5`` is the *mean* of the two
    muscles' responses, so the chirp window cannot tell which muscle is the faster one:
    ``(wn, zeta, rho_w, rho_z)`` and ``(wn rho_w, zeta rho_z, 1/rho_w, 1/rho_z)`` predict
    the same force. We report the orientation with ``wn_ratio >= 1`` (flexor the faster);
    returns the ratios and whether they were flipped.
    """
    if wn_ratio < 1.0:
        return 1.0 / wn_ratio, 1.0 / zeta_ratio, True
    return wn_ratio, zeta_ratio, False


class AsymmetryForm(FittedForm):
    """The flexor's ``wn * rho_w``, ``zeta * rho_z``; ``q = log rho``."""

    n = 2
    bounds = ((float(np.log(0.2)), float(np.log(5.0))),) * 2

    def grid(self):
        return [[float(np.log(r)), float(np.log(z))] for r in (0.4, 0.6, 0.8, 1.25, 1.7, 2.5)
                for z in (0.6, 1.0, 1.6)]

    def physical(self, q):
        return {"wn_ratio": float(np.exp(q[0])), "zeta_ratio": float(np.exp(q[1]))}

    def fit_flexor_ratios(self, q):
        rw, rz = np.exp(q)
        return rw, rz

    def final(self, p, ctx):
        wr, zr, flipped = canonical_asymmetry(p["wn_ratio"], p["zeta_ratio"])
        p["wn_ratio"], p["zeta_ratio"] = wr, zr
        p["orientation_flipped"] = flipped

    def twin_params(self, p, sE_levels):
        return {"wn_ratio": p["wn_ratio"], "zeta_ratio": p["zeta_ratio"]}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: gain/phase error of resonance shape (max phase error "
                f"{tf.max_abs_phase_error_deg:.1f} deg, not linear: R^2 "
                f"{tf.r2_linear_phase:.2f}); the mixture of two second-order "
                "responses explains it.")


EFFECT = EffectDefinition(FlexorExtensorAsymmetry, AsymmetryForm())
