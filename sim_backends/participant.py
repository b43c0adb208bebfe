"""The virtual participant: two muscles, co-activation-dependent second-order dynamics.

Model (all currents are the ones really delivered, after the stimulator's quantisation)
----------------------------------------------------------------------------------------
Each muscle m has a reference calibration ``Imin_m`` / ``Imax_m`` (the currents at which
it alone produces ``Fmin_N`` / ``Fmax_N`` on a ``step_mA`` ramp; they lie on the ramp's
grid) and normalised intensity ``u_m = (I'_m - Imin_m) / (Imax_m - Imin_m)`` (paper
eqs. 1-2).

* **Alone** (the antagonist below its Imin, e.g. a calibration ramp): the muscle's static
  force follows its own piecewise-linear recruitment in mA: zero up to a threshold
  current, rising linearly to ``c_m`` at ``Imin_m``, slope ``(Fmax - Fmin) / (Imax_m -
  Imin_m)`` N/mA above it, saturating at ``u_sat``. ``c_m = Fmin + (Fmax - Fmin) q / 2``
  with ``q = step_mA / (Imax_m - Imin_m)``, so each ramp crossing (Fmin at Imin, Fmax at
  Imax) lies half a step's force increment inside the step: a 0.5 mA ramp finds exactly
  the reference calibration, with margin against sensor noise.
* **Co-activated** (both at or above their Imin, as in every identification trial): with
  ``sE = u_e + u_f`` (eq. 4), each muscle's force is ``Fmin + k(sE) h(u_m)``, ``k(sE) =
  Kp(sE) / (2 sE)``, ``h`` the identity unless ``recruitment_nonlinearity`` is on; the
  extensor also carries the participant's static offset ``offset_N(sE)``.
* **Endpoint**: extensor minus flexor, each through unity-gain second-order dynamics
  ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` with ``wn(sE)``, ``zeta(sE)`` (identical for both
  muscles unless ``flexor_extensor_asymmetry`` is on).

With linear recruitment and symmetric dynamics the endpoint force in a trial at constant
sE is exactly the twin model ``y'' + 2 zeta wn y' + wn^2 y = Kp wn^2 (rE - 0.5)`` plus
``offset_N(sE)`` (``docs/twin-file.md``). Parameters are evaluated at sE clipped to
``sE_range`` (the curves are fits over that range; outside it they are held at the end
values rather than extrapolated).

Why the two regimes: a co-activation-dependent gain cannot also reproduce the single-muscle
calibration ramp for every Kp curve (at sE = 1, rE = 1 the extensor alone would have to
give Fmax); the paper's normalisation is defined by the single-muscle ramps and its model
by co-activated trials, so each is modelled where it is measured. No trial ever leaves the
co-activated regime (rE in [0, 1] keeps both muscles at or above Imin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from nmsid.protocols.effects import chain_of
from nmsid.protocols.session_file import Calibration
from nmsid.sim_backends.curves import CurveModel, ParameterCurve
from nmsid.sim_backends.effects import EFFECT_TYPES, effects_from_list, effects_to_list
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.sensor import SensorModel

#: A muscle within this much below its Imin still counts as recruited (co-activated
#: regime): the stimulator's 1 uA quantisation and float rounding in the inversion of
#: eqs. 1-4 can put rE = 0 / 1 a hair below Imin. Far below a ramp step, so a
#: single-muscle ramp (antagonist at 0 mA) is never mistaken for co-activation.
COACTIVE_TOL_MA = 0.05

SE_RESOLUTION = 1e-3
"""Resolution of the co-activation the simulated muscles sense (their parameters are
evaluated on this grid of sE)."""


def sensed_sE(sE: float) -> float:
    """sE as the simulated participant senses it (rounded to ``SE_RESOLUTION``, > 0)."""
    s = round(round(float(sE) / SE_RESOLUTION) * SE_RESOLUTION, 9)
    return s if s > 0 else SE_RESOLUTION


class TrueParameters(NamedTuple):
    """What the identification should recover at one sE."""

    Kp: float
    """Gain, N per unit rE."""
    wn_rad_s: float
    zeta: float


@dataclass(frozen=True)
class ReferenceCalibration:
    """The participant's own Imin / Imax per muscle (what a ``step_mA`` ramp finds)."""

    Iemin_mA: float
    Iemax_mA: float
    Ifmin_mA: float
    Ifmax_mA: float
    Fmin_N: float = 0.5
    Fmax_N: float = 5.0
    step_mA: float = 0.5

    def __post_init__(self):
        for name in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N",
                     "step_mA"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise SimConfigError(f"calibration {name} must be finite, got {v!r}")
            object.__setattr__(self, name, v)
        if not (self.Iemax_mA > self.Iemin_mA > 0 and self.Ifmax_mA > self.Ifmin_mA > 0):
            raise SimConfigError(
                "calibration needs Iemax_mA > Iemin_mA > 0 and Ifmax_mA > Ifmin_mA > 0, got "
                f"{self.Iemin_mA:g}/{self.Iemax_mA:g} and {self.Ifmin_mA:g}/{self.Ifmax_mA:g}")
        if not (self.Fmax_N > self.Fmin_N > 0):
            raise SimConfigError(f"calibration needs Fmax_N > Fmin_N > 0, got "
                                 f"{self.Fmin_N:g}/{self.Fmax_N:g}")
        if not self.step_mA > 0:
            raise SimConfigError(f"calibration step_mA must be > 0, got {self.step_mA!r}")

    def span_mA(self, muscle: str) -> float:
        return (self.Iemax_mA - self.Iemin_mA) if muscle == "ext" else \
            (self.Ifmax_mA - self.Ifmin_mA)

    def imin_mA(self, muscle: str) -> float:
        return self.Iemin_mA if muscle == "ext" else self.Ifmin_mA

    def as_session_calibration(self):
        """The same currents as a :class:`nmsid.protocols.session_file.Calibration`."""
        return Calibration(self.Iemin_mA, self.Iemax_mA, self.Ifmin_mA, self.Ifmax_mA,
                           self.Fmin_N, self.Fmax_N)

    def matches(self, cal, tol_mA: float = 1e-9) -> bool:
        """True if ``cal`` (any object with the four current attributes) has these currents."""
        return all(abs(float(getattr(cal, n)) - getattr(self, n)) <= tol_mA
                   for n in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA"))


@dataclass(frozen=True)
class OperatingPoint:
    """Everything the simulator needs at one co-activation (cached per sE)."""

    sE: float
    Kp: float
    wn_rad_s: float
    zeta: float
    k_N: float
    offset_N: float


@dataclass(frozen=True)
class VirtualParticipant:
    """A simulated participant (see the module docstring for the model).

    Parameters
    ----------
    code : str
        Participant code, ``[A-Za-z0-9_-]{1,64}``.
    Kp, wn_rad_s, zeta : ParameterCurve
        Nominal parameter curves of sE (Kp in N per unit rE, wn in rad/s).
    calibration : ReferenceCalibration
        The participant's Imin / Imax per muscle (on the ramp grid).
    offset_N : ParameterCurve
        Static endpoint offset of the co-activated muscles as a function of sE, N.
    sE_range : (float, float)
        Range over which the curves hold; parameters are clipped to it.
    effects : tuple
        Enabled optional effects (:mod:`nmsid.sim_backends.effects`), at most one of each name.
    sensor : SensorModel
        The measurement chain.
    seed : int
        Seeds the sensor noise and the baseline wander.
    u_saturation : float
        Normalised intensity at which a muscle's recruitment saturates.
    """

    code: str = "SIM01"
    Kp: ParameterCurve = field(default_factory=lambda: ParameterCurve(
        CurveModel.EXPONENTIAL, (1.35, 1.9)))
    wn_rad_s: ParameterCurve = field(default_factory=lambda: ParameterCurve(
        CurveModel.QUADRATIC, (10.0, 40.0, -25.0)))
    zeta: ParameterCurve = field(default_factory=lambda: ParameterCurve(
        CurveModel.QUADRATIC, (0.1585, 0.91, -0.35)))
    calibration: ReferenceCalibration = field(default_factory=lambda: ReferenceCalibration(
        2.0, 9.5, 1.5, 8.0))
    offset_N: ParameterCurve = field(default_factory=lambda: ParameterCurve.constant(0.0))
    sE_range: tuple[float, float] = (0.30, 1.00)
    effects: tuple = ()
    sensor: SensorModel = field(default_factory=SensorModel)
    seed: int = 0
    u_saturation: float = 1.5

    def __post_init__(self):
        import re
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", str(self.code)):
            raise SimConfigError(f"participant code {self.code!r} must match "
                                 "[A-Za-z0-9_-]{1,64}")
        lo, hi = (float(x) for x in self.sE_range)
        if not (0 < lo < hi):
            raise SimConfigError(f"sE_range must be (lo, hi) with 0 < lo < hi, got "
                                 f"{self.sE_range!r}")
        object.__setattr__(self, "sE_range", (lo, hi))
        object.__setattr__(self, "effects", tuple(effects_from_list(list(self.effects))))
        grid = np.linspace(lo, hi, 29)
        # Kp and the offset in N, or N m for a torque joint (a knee's Kp reaches ~100 N m)
        checks = (("Kp", self.Kp(grid), 0.0, 1000.0),
                  ("wn_rad_s", self.wn_rad_s(grid), 0.5, 500.0),
                  ("zeta", self.zeta(grid), 0.01, 10.0),
                  ("offset_N", self.offset_N(grid), -1000.0, 1000.0))
        for name, vals, vmin, vmax in checks:
            vals = np.atleast_1d(vals)
            if not (np.all(np.isfinite(vals)) and vals.min() > vmin and vals.max() < vmax):
                raise SimConfigError(
                    f"participant {self.code}: {name} curve leaves ({vmin:g}, {vmax:g}) over "
                    f"sE_range {self.sE_range}: min {vals.min():.4g}, max {vals.max():.4g}")
        if not self.u_saturation > 1.0:
            raise SimConfigError(f"u_saturation must be > 1, got {self.u_saturation!r}")

    # -- parameters ----------------------------------------------------------------------
    def effect(self, name: str):
        """The enabled effect of that name, or None."""
        if name not in EFFECT_TYPES:
            raise SimConfigError(f"effect name {name!r} is unknown; valid: "
                                 f"{', '.join(EFFECT_TYPES)}")
        return next((e for e in self.effects if e.name == name), None)

    def with_effects(self, *effects) -> VirtualParticipant:
        """A copy with these effects (dataclasses or twin-file dicts) added or replaced."""
        new = effects_from_list(list(effects))
        names = {e.name for e in new}
        return replace(self, effects=tuple(e for e in self.effects if e.name not in names)
                       + tuple(new))

    def operating_point(self, sE: float) -> OperatingPoint:
        """Parameters at a co-activation sE (clipped to ``sE_range`` for the curves)."""
        lo, hi = self.sE_range
        s = float(sE)
        sc = min(max(s, lo), hi)
        Kp_c = float(self.Kp(sc))
        return OperatingPoint(sE=s, Kp=Kp_c * (s / sc) if s > 0 else Kp_c,
                              wn_rad_s=float(self.wn_rad_s(sc)), zeta=float(self.zeta(sc)),
                              k_N=Kp_c / (2.0 * sc), offset_N=float(self.offset_N(sc)))

    def true_parameters(self, sE: float, calibration=None) -> TrueParameters:
        """The Kp, wn, zeta that identification should recover from a trial at ``sE``.

        Parameters
        ----------
        sE : float
            The trial's EAA sum as the session commanded it.
        calibration : optional
            The calibration the session used (any object with ``Iemin_mA``, ``Iemax_mA``,
            ``Ifmin_mA``, ``Ifmax_mA``). None or the participant's reference calibration
            (what the 0.5 mA ramp finds on it): the curves at sE, exactly. Another
            calibration: the currents it really delivers at rE = 0.5 give the
            participant's own co-activation and gain (a linearisation if the two muscles'
            spans are rescaled differently, since sE then varies with rE in the trial).

        Returns
        -------
        TrueParameters
            ``(Kp, wn_rad_s, zeta)`` of the nominal model; the enabled effects are in
            :meth:`effect_truth`.
        """
        if calibration is None or self.calibration.matches(calibration):
            op = self.operating_point(sensed_sE(sE))
            return TrueParameters(2.0 * op.k_N * sE, op.wn_rad_s, op.zeta)
        ref = self.calibration
        spans = {}
        u = {}
        for m, imin, imax, share in (("ext", "Iemin_mA", "Iemax_mA", 0.5),
                                     ("flex", "Ifmin_mA", "Ifmax_mA", 0.5)):
            lo_c, hi_c = float(getattr(calibration, imin)), float(getattr(calibration, imax))
            current = lo_c + share * sE * (hi_c - lo_c)
            u[m] = (current - ref.imin_mA(m)) / ref.span_mA(m)
            spans[m] = (hi_c - lo_c) / ref.span_mA(m)
        if u["ext"] * ref.span_mA("ext") < -COACTIVE_TOL_MA or \
                u["flex"] * ref.span_mA("flex") < -COACTIVE_TOL_MA:
            raise SimConfigError(
                f"with calibration {calibration!r} a muscle is below its Imin at rE = 0.5, "
                f"sE = {sE:g}: the participant is not co-activated, no second-order truth")
        op = self.operating_point(sensed_sE(u["ext"] + u["flex"]))
        Kp = op.k_N * sE * (spans["ext"] + spans["flex"])
        return TrueParameters(Kp, op.wn_rad_s, op.zeta)

    def effect_truth(self) -> list[dict]:
        """The enabled effects in twin-file form ``[{"name": ..., "params": {...}}]``."""
        return effects_to_list(self.effects)

    # -- static recruitment ------------------------------------------------------------
    def ramp_force_at_imin_N(self, muscle: str) -> float:
        """``c_m``: the muscle's single-muscle force at its Imin."""
        cal = self.calibration
        q = cal.step_mA / cal.span_mA(muscle)
        return cal.Fmin_N + 0.5 * (cal.Fmax_N - cal.Fmin_N) * q

    def single_muscle_force_N(self, muscle: str, current_mA):
        """Static force magnitude of one muscle stimulated alone (recruitment curve), N."""
        cal = self.calibration
        I = np.asarray(current_mA, dtype=float)
        span = cal.span_mA(muscle)
        imin = cal.imin_mA(muscle)
        c = self.ramp_force_at_imin_N(muscle)
        k1 = cal.Fmax_N - cal.Fmin_N
        u = (I - imin) / span
        above = c + k1 * np.minimum(u, self.u_saturation)
        i_th = max(0.0, imin - c * span / k1)
        below = c * np.clip((I - i_th) / (imin - i_th), 0.0, 1.0)
        out = np.where(u >= 0, above, below)
        return float(out) if np.ndim(out) == 0 else out

    def ramp_calibration(self, step_mA: float | None = None, ceiling_mA: float = 16.0
                         ) -> ReferenceCalibration:
        """What a noiseless ramp (``step, 2 step, ...``) finds: first step >= Fmin, >= Fmax."""
        cal = self.calibration
        step = cal.step_mA if step_mA is None else float(step_mA)
        grid = np.round(step * np.arange(1, int(ceiling_mA / step + 1e-9) + 1), 9)
        found = {}
        for m in ("ext", "flex"):
            f = self.single_muscle_force_N(m, grid)
            i_min = np.flatnonzero(f >= cal.Fmin_N)
            i_max = np.flatnonzero(f >= cal.Fmax_N)
            if not i_min.size or not i_max.size:
                raise SimConfigError(f"participant {self.code}: the {m} ramp up to "
                                     f"{ceiling_mA:g} mA never reaches Fmin/Fmax")
            found[m] = (float(grid[i_min[0]]), float(grid[i_max[0]]))
        return ReferenceCalibration(found["ext"][0], found["ext"][1], found["flex"][0],
                                    found["flex"][1], cal.Fmin_N, cal.Fmax_N, step)

    def normalised(self, muscle: str, current_mA):
        """``u_m`` of delivered currents (reference calibration)."""
        cal = self.calibration
        return (np.asarray(current_mA, dtype=float) - cal.imin_mA(muscle)) / cal.span_mA(muscle)

    def muscle_forces_N(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray,
                        op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
        """Static force of each muscle (magnitudes, before dynamics) for delivered currents.

        ``op`` gives the co-activation parameters (the chunk's sE).
        """
        cal = self.calibration
        u_e = self.normalised("ext", I_ext_mA)
        u_f = self.normalised("flex", I_flex_mA)
        co = ((u_e >= -COACTIVE_TOL_MA / cal.span_mA("ext"))
              & (u_f >= -COACTIVE_TOL_MA / cal.span_mA("flex")))
        chain = chain_of(self.effects)     # the effects' intensity maps (recruitment)
        Fmin = self.calibration.Fmin_N
        if np.all(co):
            ue = np.minimum(u_e, self.u_saturation)
            uf = np.minimum(u_f, self.u_saturation)
            if chain.maps_intensity:
                ue, uf = chain.h(ue), chain.h(uf)
            return Fmin + op.offset_N + op.k_N * ue, Fmin + op.k_N * uf
        f_e = self.single_muscle_force_N("ext", I_ext_mA)
        f_f = self.single_muscle_force_N("flex", I_flex_mA)
        if np.any(co):
            ue = np.minimum(u_e[co], self.u_saturation)
            uf = np.minimum(u_f[co], self.u_saturation)
            if chain.maps_intensity:
                ue, uf = chain.h(ue), chain.h(uf)
            f_e = np.array(f_e, dtype=float)
            f_f = np.array(f_f, dtype=float)
            f_e[co] = Fmin + op.offset_N + op.k_N * ue
            f_f[co] = Fmin + op.k_N * uf
        return np.asarray(f_e, dtype=float), np.asarray(f_f, dtype=float)

    def to_twin(self) -> dict:
        """This participant as a twin file (``docs/twin-file.md``)."""
        cal = self.calibration
        return {
            "format": "nmsid-twin", "format_version": 1, "participant": self.code,
            "source": ["sim_backends"],
            "calibration": {"Iemin_mA": cal.Iemin_mA, "Iemax_mA": cal.Iemax_mA,
                            "Ifmin_mA": cal.Ifmin_mA, "Ifmax_mA": cal.Ifmax_mA,
                            "Fmin_N": cal.Fmin_N, "Fmax_N": cal.Fmax_N},
            "sE_range": list(self.sE_range),
            "parameters": {"Kp": self.Kp.to_dict(), "wn_rad_s": self.wn_rad_s.to_dict(),
                           "zeta": self.zeta.to_dict()},
            "offset_N": self.offset_N.to_dict(),
            "effects": self.effect_truth(),
        }


def default_participant(seed: int = 0, **changes) -> VirtualParticipant:
    """The nominal participant, shaped like the paper's findings: Kp rising exponentially
    (2.4 -> 9.0 N per unit rE over sE 0.3 -> 1.0), wn with its peak inside the range
    (26 rad/s at sE = 0.8), zeta with its peak outside it (at sE = 1.3: rising 0.40 ->
    0.72 over the range); calibration 2.0 / 9.5 mA (extensor), 1.5 / 8.0 mA (flexor);
    no effects."""
    return replace(VirtualParticipant(seed=seed), **changes)
