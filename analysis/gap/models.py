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
from typing import TYPE_CHECKING, Callable, ClassVar

import numpy as np
from nmsid.analysis.signal_kernels import compiled as signal

from nmsid.analysis.discretize import (fractional_delay, lagged_second_order_tf, parallel_tf,
                                       second_order_tf, smooth_hold_input)
from nmsid.analysis.gap.data import GapData
from nmsid.protocols.effects import CANDIDATES, Effect, spec
from nmsid.sim_backends.effects import RecruitmentNonlinearity

if TYPE_CHECKING:  # the evidence module imports this one
    from nmsid.analysis.gap.evidence import Signatures

#: Bound of every model's correction of the session's input timing, ms.
TIMING_CORRECTION_MS = 1.0

#: The twin file's default fatigue reference (45 trials x 15 s), from the registry.
REFERENCE_STIM_S = spec(Effect.FATIGUE).param("reference_stim_s").default_value()


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

    @property
    def fits_baseline(self) -> bool:
        """True when an effect of the family acts through the per-trial nuisance basis
        (its bandwidth ``corner_Hz`` chosen on a grid rather than by the solver)."""
        return any(FORMS[e].through_nuisance for e in self.effects)

    def _slices(self) -> dict[Effect, slice]:
        out, i = {}, 0
        for e in self.effects:
            n = FORMS[e].n
            out[e] = slice(i, i + n)
            i += n
        return out

    def n_shared(self) -> int:
        """Number of the effects' shared parameters (what ``dk`` counts)."""
        return sum(FORMS[e].n for e in self.effects)

    def n_free(self) -> int:
        """Length of ``p``: the effects' parameters and the timing correction."""
        return self.n_shared() + 1

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of ``p``."""
        b = [bd for e in self.effects for bd in FORMS[e].bounds]
        b.append((-TIMING_CORRECTION_MS, TIMING_CORRECTION_MS))
        return (np.array([x[0] for x in b], float), np.array([x[1] for x in b], float))

    def start_grid(self) -> list[np.ndarray]:
        """Starting points screened for the shared parameters (single effects only; a
        pair starts from its members' own fits); the timing correction starts at 0."""
        if len(self.effects) != 1:
            return [np.zeros(self.n_free())]
        return [np.array(list(g) + [0.0], float) for g in FORMS[self.effects[0]].grid()]

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
            out.update(FORMS[e].physical(p[sl]))
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
            u = u + recruitment_basis(data).excess(p[sl[Effect.RECRUITMENT_NONLINEARITY]])
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


class RecruitmentBasis:
    """:func:`recruitment_excess` of our knot curve as a linear combination, for one data set.

    The knot curve is a cubic Hermite spline: on each knot interval ``h(I)`` is linear in the
    knot values ``v_j`` and slopes ``d_j`` (PCHIP chooses the slopes from the values; the
    spline is linear in both). The net drive, the low-pass and the hold correction are linear
    too, so the excess is ``sum_j v_j P_j + d_j Q_j + C`` with ``P_j``, ``Q_j``, ``C`` the
    filtered responses to the Hermite basis functions, computed once per data set: a fit's
    hundreds of evaluations then cost one weighted sum each instead of a spline evaluation
    and a zero-phase filter of every trial (equal to rounding; tests compare both).
    """

    def __init__(self, data: GapData):
        x = RECRUITMENT_KNOTS
        sE = np.array([t.sE for t in data.trials])[:, None]
        rE = data.rE_sim
        sos = _lowpass_sos(data)

        def filtered(sig):
            return smooth_hold_input(signal.sosfiltfilt(sos, sig, axis=-1))

        parts = []
        for intensity in (rE * sE, (1 - rE) * sE):
            ic = np.clip(intensity, 0.0, 1.0)
            k = np.clip(np.searchsorted(x, ic, side="right") - 1, 0, len(x) - 2)
            width = x[k + 1] - x[k]
            t = (ic - x[k]) / width
            parts.append((k, width, t, intensity - ic))
        values, slopes = [], []
        for j in range(len(x)):
            pv, pd = [], []
            for k, width, t, _ in parts:
                t2, t3 = t * t, t * t * t
                v = np.where(k == j, 2 * t3 - 3 * t2 + 1, 0.0) + \
                    np.where(k + 1 == j, -2 * t3 + 3 * t2, 0.0)
                d = np.where(k == j, (t3 - 2 * t2 + t) * width, 0.0) + \
                    np.where(k + 1 == j, (t3 - t2) * width, 0.0)
                pv.append(v)
                pd.append(d)
            values.append((pv[0] - pv[1]) / (2 * sE))
            slopes.append((pd[0] - pd[1]) / (2 * sE))
        # outside [0, 1] the curve continues with unit slope; the linear drive is taken off
        const = (parts[0][3] - parts[1][3]) / (2 * sE) - (rE - 0.5)
        # v_0 = 0 and v_last = 1 for every curve: the last value's term is constant
        self._const = filtered(const + values[-1])
        self._shape = self._const.shape
        # one (n_terms, n_samples) matrix: an evaluation is one matrix-vector product
        self._terms = np.stack([filtered(v).ravel() for v in values[1:-1]]
                               + [filtered(d).ravel() for d in slopes])

    def excess(self, q: np.ndarray) -> np.ndarray:
        """(n_trials, n_sim) :func:`recruitment_excess` of :func:`recruitment_curve` (q)."""
        from scipy.interpolate import PchipInterpolator  # the curve's own slopes
        v = recruitment_knot_values(q)
        d = PchipInterpolator(RECRUITMENT_KNOTS, v)(RECRUITMENT_KNOTS, 1)
        return self._const + (np.concatenate([v[1:-1], d]) @ self._terms).reshape(self._shape)


#: The basis of the latest data sets (a fit evaluates the model hundreds of times on one
#: data set; its folds and held-out sets are others): id -> (data, basis), newest last.
_BASES: list[tuple[GapData, RecruitmentBasis]] = []


def recruitment_basis(data: GapData) -> RecruitmentBasis:
    """The :class:`RecruitmentBasis` of ``data`` (kept for the two latest data sets)."""
    for i, (d, b) in enumerate(_BASES):
        if d is data:
            _BASES.append(_BASES.pop(i))
            return b
    b = RecruitmentBasis(data)
    _BASES.append((data, b))
    del _BASES[:-2]
    return b


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


NOMINAL = Candidate(())


def candidate(*effects: Effect) -> Candidate:
    """The model family with these effects (none: the nominal model)."""
    return Candidate(tuple(Effect(e) for e in effects if Effect(e) is not Effect.NONE))


# -- each effect's form: what the fit, the report and the twin file need of it --------------
# One class per effect of the registry (nmsid.protocols.effects), each the only place in the
# analysis that names its effect's parameters. How an effect enters the model (the drive,
# the dynamics, the gain) is Candidate.drive / level_tfs / gain above, in the order of
# physics.

def fatigue_loss_pct(rate_per_s: float, reference_stim_s: float = REFERENCE_STIM_S) -> float:
    """Gain lost over ``reference_stim_s`` of stimulation at a constant relative rate."""
    return 100.0 * (1.0 - math.exp(-rate_per_s * reference_stim_s))


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
    """The simulator-shape parameters whose net static map is closest to our curve ``h``."""
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
            params = {"shape": shape, **dict(zip(names, (float(x) for x in v)))}
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
                best = {"shape": shape, **dict(zip(names, (float(x) for x in v)))}
    return best or {}


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


@dataclass(frozen=True)
class FinalContext:
    """What an effect's :meth:`EffectForm.final` may use of the final (all-trial) fit.

    Attributes
    ----------
    q : numpy.ndarray
        The effect's own entries of the fit's unconstrained parameter vector.
    sE_levels : numpy.ndarray
        The session's sE levels.
    drift_amplitude : callable
        ``() -> (window RMS N, corrected amplitude N)`` of the fitted slow baseline
        (computed only when asked).
    """

    q: np.ndarray
    sE_levels: np.ndarray
    drift_amplitude: Callable[[], tuple[float, float]]


class EffectForm:
    """The analysis's form of one effect (subclasses: one per registry entry).

    Attributes
    ----------
    effect : Effect
    n : int
        Number of shared (all-sE) parameters the solver fits.
    bounds : tuple of (float, float)
        Their bounds on the solver's unconstrained scale.
    through_nuisance : bool
        The effect acts through the per-trial nuisance basis (baseline drift).
    """

    effect: ClassVar[Effect]
    n: ClassVar[int] = 1
    bounds: ClassVar[tuple[tuple[float, float], ...]] = ()
    through_nuisance: ClassVar[bool] = False

    def grid(self) -> list[list[float]]:
        """Starting points screened for the shared parameters."""
        return [[]]

    def physical(self, q: np.ndarray) -> dict[str, float]:
        """Our physical parameters from the solver's ``q``."""
        return {}

    def final(self, p: dict, ctx: FinalContext) -> None:
        """Add the derived figures of the final fit to ``p`` (in place)."""

    def twin_params(self, p: dict, sE_levels) -> dict:
        """The twin file's ``params`` of the effect (the registry's names)."""
        raise NotImplementedError

    def signature(self, sig: Signatures) -> str:
        """One line: the signature in the data that points at this effect (``sig.phase``:
        the transfer-function view it is judged on)."""
        raise NotImplementedError


_LOG_TIME_BOUNDS = ((float(np.log(1e-6)), float(np.log(0.3))),)
_LOG_TIME_GRID = (0.003, 0.008, 0.015, 0.025, 0.04, 0.06, 0.09, 0.13)


class DeadTimeForm(EffectForm):
    """``x(t) = x0(t - L)``; ``q = log L``."""

    effect = Effect.DEAD_TIME
    bounds = _LOG_TIME_BOUNDS

    def grid(self):
        return [[float(np.log(v))] for v in _LOG_TIME_GRID]

    def physical(self, q):
        return {"L_s": float(np.exp(q[0]))}

    def final(self, p, ctx):
        # counted from the rE record: the rig's timing and the participant's latency
        # together (the two are one delay to the data)
        p["L_s"] = p["L_s"] + p["input_timing_s"]

    def twin_params(self, p, sE_levels):
        return {"L_s": p["L_s"]}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: the effect's footprint on the transfer function is a phase "
                f"line (R^2 {tf['r2_linear_phase']:.3f} vs {tf['r2_atan_phase']:.3f} for "
                f"an arctangent; slope = {1000 * tf['dead_time_equivalent_s']:.1f} ms) with "
                f"a gain error of {tf['gain_error_at_top_dB']:.2f} dB at the top of the "
                f"band (a lag with that phase would roll off "
                f"{tf['gain_rolloff_expected_for_lag_dB']:.2f} dB).")


class ActivationDynamicsForm(EffectForm):
    """A first-order lag ``1 / (tau s + 1)``; ``q = log tau``."""

    effect = Effect.ACTIVATION_DYNAMICS
    bounds = _LOG_TIME_BOUNDS

    def grid(self):
        return [[float(np.log(v))] for v in _LOG_TIME_GRID]

    def physical(self, q):
        return {"tau_s": float(np.exp(q[0]))}

    def twin_params(self, p, sE_levels):
        return {"tau_s": p["tau_s"]}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: the footprint's phase is an arctangent (R^2 "
                f"{tf['r2_atan_phase']:.3f} vs {tf['r2_linear_phase']:.3f} for a line; tau "
                f"= {1000 * tf['lag_equivalent_s']:.1f} ms) with a gain roll-off of "
                f"{tf['gain_error_at_top_dB']:.2f} dB at the top of the band (expected "
                f"{tf['gain_rolloff_expected_for_lag_dB']:.2f} dB).")


class FatigueForm(EffectForm):
    """Gain ``exp(-lambda c)``; ``q = lambda`` in 1e-3 per s."""

    effect = Effect.FATIGUE
    bounds = ((-5.0, 5.0),)

    def grid(self):
        return [[v] for v in (-0.3, 0.0, 0.3, 0.7, 1.2)]

    def physical(self, q):
        return {"rate_per_s": float(q[0] * 1e-3)}

    def final(self, p, ctx):
        p["gain_loss_pct"] = fatigue_loss_pct(p["rate_per_s"])

    def twin_params(self, p, sE_levels):
        return {"shape": "exponential",
                "gain_loss_pct": max(0.0, fatigue_loss_pct(p["rate_per_s"])),
                "reference_stim_s": REFERENCE_STIM_S}

    def signature(self, sig):
        g = sig.gain_vs_stimulation
        return (f"signature: trial gain changes by {g['slope_per_100s']:+.4f} per 100 s of "
                f"cumulative stimulation (correlation {g['correlation']:+.2f}).")


class RecruitmentForm(EffectForm):
    """Our knot curve (:func:`recruitment_curve`); ``q``: log increments of the knots."""

    effect = Effect.RECRUITMENT_NONLINEARITY
    n = len(RECRUITMENT_KNOTS) - 2
    bounds = ((-4.0, 4.0),) * (len(RECRUITMENT_KNOTS) - 2)

    def grid(self):
        return _recruitment_grid()

    def physical(self, q):
        return {f"h_{k:.2f}": float(v) for k, v in
                zip(RECRUITMENT_KNOTS[1:-1], recruitment_knot_values(q)[1:-1])}

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


class AsymmetryForm(EffectForm):
    """The flexor's ``wn * rho_w``, ``zeta * rho_z``; ``q = log rho``."""

    effect = Effect.FLEXOR_EXTENSOR_ASYMMETRY
    n = 2
    bounds = ((float(np.log(0.2)), float(np.log(5.0))),) * 2

    def grid(self):
        return [[float(np.log(r)), float(np.log(z))] for r in (0.4, 0.6, 0.8, 1.25, 1.7, 2.5)
                for z in (0.6, 1.0, 1.6)]

    def physical(self, q):
        return {"wn_ratio": float(np.exp(q[0])), "zeta_ratio": float(np.exp(q[1]))}

    def final(self, p, ctx):
        wr, zr, flipped = canonical_asymmetry(p["wn_ratio"], p["zeta_ratio"])
        p["wn_ratio"], p["zeta_ratio"] = wr, zr
        p["orientation_flipped"] = flipped

    def twin_params(self, p, sE_levels):
        return {"wn_ratio": p["wn_ratio"], "zeta_ratio": p["zeta_ratio"]}

    def signature(self, sig):
        tf = sig.phase
        return (f"signature: gain/phase error of resonance shape (max phase error "
                f"{tf['max_abs_phase_error_deg']:.1f} deg, not linear: R^2 "
                f"{tf['r2_linear_phase']:.2f}); the mixture of two second-order "
                "responses explains it.")


class BaselineDriftForm(EffectForm):
    """Cosines up to ``corner_Hz`` in the nuisance basis; no solver parameter."""

    effect = Effect.BASELINE_DRIFT
    n = 0
    through_nuisance = True

    def final(self, p, ctx):
        p["window_nonlinear_rms_N"], p["amplitude_N"] = ctx.drift_amplitude()

    def twin_params(self, p, sE_levels):
        return {"amplitude_N": p.get("amplitude_N", 0.0), "corner_Hz": p["corner_Hz"]}

    def signature(self, sig):
        lf = sig.low_frequency
        return (f"signature: {100 * lf['share_below_chirp']:.0f} % of the residual power "
                f"lies below the chirp band, {lf['excess']:.0f} x the white-noise share.")


_FORM_CLASSES: tuple[type[EffectForm], ...] = (
    DeadTimeForm, ActivationDynamicsForm, FatigueForm, RecruitmentForm, AsymmetryForm,
    BaselineDriftForm)

#: Effect -> its form, in the registry's order of physics (every candidate has one).
FORMS: dict[Effect, EffectForm] = {
    e: next(c() for c in _FORM_CLASSES if c.effect is e) for e in CANDIDATES}
