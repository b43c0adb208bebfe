"""The nominal model and the candidate augmentations, as fit-ready objects.

Every model predicts, for each trial, ``Kp(sE) * g_i(t) * x_i(t)`` plus per-trial nuisance
terms (offset and linear trend; a smooth baseline for ``baseline_drift``). ``x_i`` is the
unit-gain response of the (augmented) dynamics with the per-sE ``wn`` and ``zeta`` to the
trial's drive, ``g_i`` a slowly varying gain (fatigue) and ``Kp`` is solved in closed form
(variable projection). Each augmentation adds a few parameters shared by all sE levels.

The augmentations are written from the physics, in this package's own parameterisation,
and translated to the twin file's names (``docs/twin-file.md``) only when written out:

- ``dead_time``: the force answers the drive ``L`` seconds late, ``x(t) = x0(t - L)``.
- ``activation_dynamics``: a first-order lag ``1 / (tau s + 1)`` of each muscle's
  activation; both muscles share it, so it multiplies the net transfer function.
- ``fatigue``: the gain decays with cumulative stimulation ``c`` as ``exp(-lambda c)``
  (a constant relative loss rate; a linear decline with the same end point has the same
  integrated log-slope, so the reported loss over ``reference_stim_s`` matches both).
- ``recruitment_nonlinearity``: each muscle's normalised intensity ``I`` (``I_e = rE sE``,
  ``I_f = (1 - rE) sE``) becomes activation ``h(I)`` through a monotone recruitment curve
  before the dynamics; net drive ``(h(I_e) - h(I_f)) / (2 sE)``. Our ``h`` is a monotone
  cubic through knots at I = 0, 0.1, 0.25, ..., 0.85, 1 (five free increments): a family-free
  cumulative distribution of motor-unit thresholds, convex, concave, S-shaped or with a
  threshold and a saturation.
- ``flexor_extensor_asymmetry``: the flexor's dynamics have ``wn * rho_w`` and
  ``zeta * rho_z``; with linear recruitment the net response to ``rE - 0.5`` is the mean
  of the two second-order systems.
- ``baseline_drift``: a slow non-linear baseline below ``corner_Hz`` (cosines up to that
  frequency, fitted per trial like the offset) that the linear detrend cannot remove.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from nmsid.analysis.gap.data import GapData
from nmsid.analysis.discretize import (fractional_delay, lagged_second_order_tf, parallel_tf,
                                       second_order_tf, smooth_hold_input)
from nmsid.analysis.gap.effects import Effect

#: Bound of every model's correction of the session's input timing, ms.
TIMING_CORRECTION_MS = 1.0

#: The twin file's default fatigue reference (45 trials x 15 s).
REFERENCE_STIM_S = 675.0


def nuisance_basis(t_s: np.ndarray, corner_Hz: float = 0.0) -> np.ndarray:
    """Orthonormal per-trial nuisance columns: offset, linear trend, and cosines
    ``cos(pi k t / T)`` up to ``corner_Hz`` (frequency ``k / (2 T)``)."""
    T = t_s[-1] - t_s[0] + (t_s[1] - t_s[0])
    tn = (t_s - t_s[0]) / T
    cols = [np.ones_like(tn), tn - 0.5]
    k_max = int(math.floor(2 * corner_Hz * T + 1e-9))
    for k in range(2, k_max + 1):  # k = 1 is nearly the linear trend already
        cols.append(np.cos(np.pi * k * tn))
    Q, _ = np.linalg.qr(np.column_stack(cols))
    return Q


def n_drift_columns(t_s: np.ndarray, corner_Hz: float) -> int:
    """How many columns beyond offset and trend :func:`nuisance_basis` adds."""
    return nuisance_basis(t_s, corner_Hz).shape[1] - 2


def kumaraswamy(I: np.ndarray, a: float, b: float) -> np.ndarray:
    """``1 - (1 - I^a)^b`` on ``I`` clipped to [0, 1]."""
    Ic = np.clip(I, 0.0, 1.0)
    return 1.0 - np.power(1.0 - np.power(Ic, a), b)


#: Per effect: number of shared parameters, their bounds (unconstrained scale) and the
#: starting grid screened before Levenberg-Marquardt refines the best point.
_SHARED = {
    Effect.DEAD_TIME: (1, [(np.log(1e-6), np.log(0.3))],
                       [[np.log(v)] for v in (0.003, 0.008, 0.015, 0.025, 0.04, 0.06, 0.09,
                                             0.13)]),
    Effect.ACTIVATION_DYNAMICS: (1, [(np.log(1e-6), np.log(0.3))],
                                 [[np.log(v)] for v in (0.003, 0.008, 0.015, 0.025, 0.04,
                                                       0.06, 0.09, 0.13)]),
    Effect.FATIGUE: (1, [(-5.0, 5.0)], [[v] for v in (-0.3, 0.0, 0.3, 0.7, 1.2)]),
    Effect.RECRUITMENT_NONLINEARITY: None,  # filled in below (depends on the knots)
    Effect.FLEXOR_EXTENSOR_ASYMMETRY: (
        2, [(np.log(0.2), np.log(5.0))] * 2,
        [[np.log(r), np.log(z)] for r in (0.4, 0.6, 0.8, 1.25, 1.7, 2.5)
         for z in (0.6, 1.0, 1.6)]),
    Effect.BASELINE_DRIFT: (0, [], [[]]),
}


@dataclass(frozen=True)
class Candidate:
    """A model family: the nominal second-order model (no effects), one augmentation, or
    a pair of them.

    Shared parameters are optimised on an unconstrained scale (vector ``p``, the effects'
    parameters concatenated in :attr:`effects` order) and mapped to physical values by
    :meth:`params`. ``baseline_drift`` has no such parameter: its bandwidth is chosen on a
    grid (see ``analysis.gap.diagnose``) and it acts through the nuisance basis.

    Every model, the nominal one included, also carries the last entry of ``p``: a
    correction of the rig's input timing in ms (within +-``TIMING_CORRECTION_MS``), on top
    of the session's estimate (:mod:`nmsid.analysis.input_timing`, made with a plain
    second-order fit, which an effect outside it can pull). Each model thus gets the
    timing that suits it, and since all carry it, it never counts in ``dk``.
    """

    effects: tuple[Effect, ...] = ()

    @property
    def effect(self) -> Effect:
        """The single effect (``NONE`` for the nominal model)."""
        return self.effects[0] if len(self.effects) == 1 else Effect.NONE

    @property
    def label(self) -> str:
        return "+".join(e.value for e in self.effects) or Effect.NONE.value

    def _slices(self) -> dict[Effect, slice]:
        out, i = {}, 0
        for e in self.effects:
            n = _SHARED[e][0]
            out[e] = slice(i, i + n)
            i += n
        return out

    def n_shared(self) -> int:
        """Number of the effects' shared parameters (what ``dk`` counts)."""
        return sum(_SHARED[e][0] for e in self.effects)

    def n_free(self) -> int:
        """Length of ``p``: the effects' parameters and the timing correction."""
        return self.n_shared() + 1

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of ``p``."""
        b = [bd for e in self.effects for bd in _SHARED[e][1]]
        b.append((-TIMING_CORRECTION_MS, TIMING_CORRECTION_MS))
        return (np.array([x[0] for x in b], float), np.array([x[1] for x in b], float))

    def start_grid(self) -> list[np.ndarray]:
        """Starting points screened for the shared parameters (single effects only; a
        pair starts from its members' own fits); the timing correction starts at 0."""
        if len(self.effects) != 1:
            return [np.zeros(self.n_free())]
        return [np.array(list(g) + [0.0], float) for g in _SHARED[self.effects[0]][2]]

    def timing_s(self, p: np.ndarray) -> float:
        """The timing correction in s (0 when ``p`` has no entry for it)."""
        return float(p[self.n_shared()]) * 1e-3 if len(p) > self.n_shared() else 0.0

    def sub(self, p: np.ndarray, effect: Effect) -> np.ndarray:
        """The part of ``p`` that belongs to ``effect``."""
        return p[self._slices()[effect]]

    def params(self, p: np.ndarray) -> dict[str, float]:
        """Physical shared parameters (our own parameterisation) from ``p``."""
        out: dict[str, float] = {}
        for e, sl in self._slices().items():
            q = p[sl]
            if e is Effect.DEAD_TIME:
                out["L_s"] = float(np.exp(q[0]))
            elif e is Effect.ACTIVATION_DYNAMICS:
                out["tau_s"] = float(np.exp(q[0]))
            elif e is Effect.FATIGUE:
                out["rate_per_s"] = float(q[0] * 1e-3)
            elif e is Effect.RECRUITMENT_NONLINEARITY:
                out.update({f"h_{k:.2f}": float(v) for k, v in
                            zip(RECRUITMENT_KNOTS[1:-1], recruitment_knot_values(q)[1:-1])})
            elif e is Effect.FLEXOR_EXTENSOR_ASYMMETRY:
                out["wn_ratio"], out["zeta_ratio"] = float(np.exp(q[0])), float(np.exp(q[1]))
        out["timing_correction_s"] = self.timing_s(p)
        return out

    # -- the model ----------------------------------------------------------------------
    def level_tfs(self, wn: np.ndarray, zeta: np.ndarray, p: np.ndarray, dt_s: float):
        """Difference equations ``(b, a)``, one row per sE level, of the unit-gain
        dynamics."""
        sl = self._slices()
        lag = Effect.ACTIVATION_DYNAMICS in sl
        asym = Effect.FLEXOR_EXTENSOR_ASYMMETRY in sl
        if lag:
            tau = float(np.exp(p[sl[Effect.ACTIVATION_DYNAMICS]][0]))
        if asym:
            rw, rz = np.exp(p[sl[Effect.FLEXOR_EXTENSOR_ASYMMETRY]])
            if lag:
                b1, a1 = lagged_second_order_tf(wn, zeta, tau, dt_s)
                b2, a2 = lagged_second_order_tf(wn * rw, zeta * rz, tau, dt_s)
            else:
                b1, a1 = second_order_tf(wn, zeta, dt_s)
                b2, a2 = second_order_tf(wn * rw, zeta * rz, dt_s)
            return parallel_tf(b1, a1, b2, a2)
        if lag:
            return lagged_second_order_tf(wn, zeta, tau, dt_s)
        return second_order_tf(wn, zeta, dt_s)

    def drive(self, data: GapData, p: np.ndarray) -> np.ndarray:
        """(n_trials, n_sim) input of the dynamics (recruitment, then dead time)."""
        sl = self._slices()
        u = data.drive_sim
        if Effect.RECRUITMENT_NONLINEARITY in sl:
            h = recruitment_curve(p[sl[Effect.RECRUITMENT_NONLINEARITY]])
            u = u + recruitment_excess(data, h)
        delay_s = self.timing_s(p)
        if Effect.DEAD_TIME in sl:
            delay_s += float(np.exp(p[sl[Effect.DEAD_TIME]][0]))
        if delay_s != 0.0:
            u = fractional_delay(u, delay_s * data.fs_sim_Hz)
        return u

    def gain(self, data: GapData, p: np.ndarray) -> np.ndarray | None:
        """(n_trials, n_eval) slowly varying gain factor, or None."""
        sl = self._slices()
        if Effect.FATIGUE in sl:
            lam = float(p[sl[Effect.FATIGUE]][0]) * 1e-3
            c = data.cum_stim_s[:, None] + data.t_eval_s[None, :]
            # relative to the session's start, never to the trials at hand: a held-out
            # trial must see the same gain law as the training trials
            return np.exp(-lam * c)
        return None


def recruitment_excess(data: GapData, h) -> np.ndarray:
    """Net drive of the recruitment curve ``h`` minus the linear drive, low-passed.

    The linear part keeps the force's own filter chain (so the identity curve is exactly
    the nominal model); the excess gets the same zero-phase low-pass at the simulation
    rate.
    """
    sE = np.array([t.sE for t in data.trials])[:, None]
    rE = data.rE_sim
    x = (h(rE * sE) - h((1 - rE) * sE)) / (2 * sE)
    return smooth_hold_input(signal.sosfiltfilt(_lowpass_sos(data), x - (rE - 0.5), axis=-1))


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


def _lowpass_sos(data: GapData):
    s = data.settings
    return signal.butter(s.lowpass_order, s.lowpass_Hz, fs=data.fs_sim_Hz, output="sos")


_SHARED[Effect.RECRUITMENT_NONLINEARITY] = (
    len(RECRUITMENT_KNOTS) - 2, [(-4.0, 4.0)] * (len(RECRUITMENT_KNOTS) - 2),
    _recruitment_grid())

NOMINAL = Candidate(())


def candidate(*effects: Effect) -> Candidate:
    """The model family with these effects (none: the nominal model)."""
    return Candidate(tuple(Effect(e) for e in effects if Effect(e) is not Effect.NONE))
