"""The nominal model and the candidate augmentations, as fit-ready objects.

Every model predicts, for each trial, ``Kp(sE) * g_i(t) * x_i(t)`` plus per-trial nuisance
terms (offset and linear trend; a smooth baseline for ``baseline_drift``). ``x_i`` is the
unit-gain response of the (augmented) dynamics with the per-sE ``wn`` and ``zeta`` to the
trial's drive, ``g_i`` a slowly varying gain (fatigue) and ``Kp`` is solved in closed form
(variable projection). Each augmentation adds a few parameters shared by all sE levels.

Each augmentation's form (its parameter vector ``q`` <-> physical values, bounds, starting
grid, where it acts, the twin file's parameters, its signature) is defined with the effect,
in its module of :mod:`nmsid.protocols.effect_defs` (:class:`FittedForm`), and read here
from the registry (:data:`FORMS`); :class:`Candidate` composes them at the chain's slots
(``intensity`` -> ``lag`` / ``flexor`` dynamics -> ``delay`` -> ``gain``; an effect
``through_nuisance`` acts through the per-trial nuisance basis) and names no effect.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from nmsid.analysis.discretize import (
    fractional_delay,
    lagged_second_order_tf,
    parallel_tf,
    second_order_tf,
    smooth_hold_input,
)
from nmsid.analysis.gap.data import GapData
from nmsid.analysis.parameters import Parameters
from nmsid.protocols.effect_defs.base import FittedForm

# re-exported: each effect's own helpers live with its definition
from nmsid.protocols.effect_defs.fatigue import REFERENCE_STIM_S, fatigue_loss_pct  # noqa: F401
from nmsid.protocols.effect_defs.flexor_extensor_asymmetry import canonical_asymmetry  # noqa: F401
from nmsid.protocols.effect_defs.recruitment_nonlinearity import (  # noqa: F401
    RECRUITMENT_KNOTS,
    net_static_map,
    nonlinearity_index_pct,
    project_recruitment,
    recruitment_curve,
    recruitment_knot_values,
)
from nmsid.protocols.effects import CANDIDATES, Effect, EffectParamError, spec

#: Bound of every model's correction of the session's input timing, ms.
TIMING_CORRECTION_MS = 1.0


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

    #: The slots :meth:`drive` reads (with the timing correction), and those
    #: :meth:`level_tfs` reads: what a cache of either must be keyed on.
    DRIVE_SLOTS: ClassVar[tuple[str, ...]] = ("intensity", "delay")
    DYNAMICS_SLOTS: ClassVar[tuple[str, ...]] = ("lag", "flexor")

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

    def params(self, p: np.ndarray) -> Parameters:
        """Physical shared parameters (our own parameterisation) from ``p``: each effect's
        (:meth:`FittedForm.physical`), then ``timing_correction_s``."""
        out: dict[str, float] = {}
        for e, sl in self._slices().items():
            out.update(FORMS[e].physical(p[sl]))
        out["timing_correction_s"] = self.timing_s(p)
        return Parameters.of(out)

    def indices_at(self, slots: tuple[str, ...], timing: bool = False) -> tuple[int, ...]:
        """Indices of ``p`` read by the effects acting at ``slots`` (with ``timing``: and
        the timing correction's)."""
        known = self._indices.get((slots, timing))
        if known is not None:
            return known
        out = {i for slot in slots for _, sl in self._slot_parts.get(slot, ())
               for i in range(sl.start, sl.stop)}
        if timing:
            out.add(self.n_shared())
        self._indices[(slots, timing)] = found = tuple(sorted(out))
        return found

    @functools.cached_property
    def _indices(self) -> dict[tuple[tuple[str, ...], bool], tuple[int, ...]]:
        """:meth:`indices_at`'s answers, kept with the candidate (a cache on the method
        would keep every candidate alive)."""
        return {}

    # -- the model: the effects' forms composed at the chain's slots -------------------
    def _at(self, slot: str, p: np.ndarray) -> list[tuple[FittedForm, np.ndarray]]:
        """(form, its part of ``p``) of each effect acting at ``slot``, in order."""
        return [(f, p[sl]) for f, sl in self._slot_parts.get(slot, ())]

    @functools.cached_property
    def _slot_parts(self) -> dict[str, tuple[tuple[FittedForm, slice], ...]]:
        """slot -> (form, its slice of ``p``) of each effect acting there (made once: the
        model is evaluated hundreds of times per fit)."""
        out: dict[str, list[tuple[FittedForm, slice]]] = {}
        for e, sl in self._slices().items():
            for slot in spec(e).source.slots:
                out.setdefault(slot, []).append((FORMS[e], sl))
        return {k: tuple(v) for k, v in out.items()}

    def level_tfs(self, wn: np.ndarray, zeta: np.ndarray, p: np.ndarray, dt_s: float):
        """Difference equations ``(b, a)``, one row per sE level, of the unit-gain
        dynamics (an activation lag in cascade; the mean of two paths when an effect acts
        on the flexor's dynamics)."""
        lags = self._at("lag", p)
        if len(lags) > 1:
            raise ValueError(f"{self.label}: more than one effect acts on the activation lag")
        tau = lags[0][0].fit_lag_s(lags[0][1]) if lags else None
        flex = self._at("flexor", p)
        if flex:
            rw, rz = flex[0][0].fit_flexor_ratios(flex[0][1])
            for f, q in flex[1:]:
                a, b = f.fit_flexor_ratios(q)
                rw, rz = rw * a, rz * b
            if tau is not None:
                b1, a1 = lagged_second_order_tf(wn, zeta, tau, dt_s)
                b2, a2 = lagged_second_order_tf(wn * rw, zeta * rz, tau, dt_s)
            else:
                b1, a1 = second_order_tf(wn, zeta, dt_s)
                b2, a2 = second_order_tf(wn * rw, zeta * rz, dt_s)
            return parallel_tf(b1, a1, b2, a2)
        if tau is not None:
            return lagged_second_order_tf(wn, zeta, tau, dt_s)
        return second_order_tf(wn, zeta, dt_s)

    def drive(self, data: GapData, p: np.ndarray) -> np.ndarray:
        """(n_trials, n_sim) input of the dynamics (intensity maps, then delays)."""
        u = data.drive_sim
        maps = self._at("intensity", p)
        if len(maps) == 1:
            u = u + intensity_excess(data, *maps[0])
        elif maps:            # composed curves: h2(h1(I))
            curves = [f.fit_curve(q) for f, q in maps]

            def h(I, curves=curves):
                for c in curves:
                    I = c(I)
                return I
            u = u + recruitment_excess(data, h)
        delay_s = self.timing_s(p)
        for f, q in self._at("delay", p):
            delay_s += f.fit_delay_s(q)
        if delay_s != 0.0:
            u = fractional_delay(u, delay_s * data.fs_sim_Hz)
        return u

    def gain(self, data: GapData, p: np.ndarray) -> np.ndarray | None:
        """(n_trials, n_eval) slowly varying gain factor, or None."""
        gains = self._at("gain", p)
        if not gains:
            return None
        # relative to the session's start, never to the trials at hand: a held-out
        # trial must see the same gain law as the training trials
        c = data.cum_stim_s[:, None] + data.t_eval_s[None, :]
        g = gains[0][0].fit_gain(gains[0][1], c)
        for f, q in gains[1:]:
            g = g * f.fit_gain(q, c)
        return g


def intensity_excess(data: GapData, form: FittedForm, q: np.ndarray) -> np.ndarray:
    """(n_trials, n_sim) :func:`recruitment_excess` of one effect's fitted intensity map:
    through the precomputed linear basis when the form is a knot curve
    (:attr:`FittedForm.knots`), else by filtering its curve."""
    if form.knots is not None:
        return recruitment_basis(data, form.knots).excess_of_values(form.knot_values(q))
    return recruitment_excess(data, form.fit_curve(q))


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

    def __init__(self, data: GapData, knots: np.ndarray = RECRUITMENT_KNOTS):
        x = self.knots = np.asarray(knots, float)
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
        return self.excess_of_values(recruitment_knot_values(q))

    def excess_of_values(self, v: np.ndarray) -> np.ndarray:
        """The excess of the PCHIP curve through the knot values ``v`` (0 first, 1 last)."""
        d = pchip_slopes(self.knots, v)
        return self._const + (np.concatenate([v[1:-1], d]) @ self._terms).reshape(self._shape)


def pchip_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The knot slopes of the PCHIP curve through ``(x, y)``, as
    ``scipy.interpolate.PchipInterpolator(x, y)(x, 1)`` computes them (equal to rounding;
    a fit evaluates them hundreds of times, and scipy's object costs ~60 us a call).

    Fritsch-Butland: zero where the neighbouring secant slopes differ in sign or one is
    zero, else their weighted harmonic mean; the ends by the one-sided three-point
    estimate, kept shape-preserving (Moler, *Numerical Computing with MATLAB*, 3.6).

    Examples
    --------
    >>> import numpy as np
    >>> pchip_slopes(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0])).tolist()
    [1.0, 1.0, 1.0]
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    h = np.diff(x)
    m = np.diff(y) / h
    if len(x) == 2:
        return np.array([m[0], m[0]])
    d = np.zeros_like(y)
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    flat = (np.sign(m[1:]) != np.sign(m[:-1])) | (m[1:] == 0) | (m[:-1] == 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        whmean = (w1 / m[:-1] + w2 / m[1:]) / (w1 + w2)
    d[1:-1][~flat] = 1.0 / whmean[~flat]

    def edge(h0, h1, m0, m1):
        e = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        if np.sign(e) != np.sign(m0):
            return 0.0
        if np.sign(m0) != np.sign(m1) and abs(e) > 3 * abs(m0):
            return 3 * m0
        return e

    d[0] = edge(h[0], h[1], m[0], m[1])
    d[-1] = edge(h[-1], h[-2], m[-1], m[-2])
    return d


#: The basis of the latest data sets (a fit evaluates the model hundreds of times on one
#: data set; its folds and held-out sets are others): id -> (data, basis), newest last.
_BASES: list[tuple[GapData, RecruitmentBasis]] = []
#: How many bases are kept: a diagnosis's three training folds, three held-out sets and
#: all trials (the recruitment candidate, then its pairs, use each again; ~6 MB a fold).
_N_BASES = 7


def recruitment_basis(data: GapData, knots: np.ndarray = RECRUITMENT_KNOTS
                      ) -> RecruitmentBasis:
    """The :class:`RecruitmentBasis` of ``data`` (kept for the ``_N_BASES`` latest data
    sets)."""
    for i, (d, b) in enumerate(_BASES):
        if d is data and (b.knots is knots or np.array_equal(b.knots, knots)):
            _BASES.append(_BASES.pop(i))
            return b
    b = RecruitmentBasis(data, knots)
    _BASES.append((data, b))
    del _BASES[:-_N_BASES]
    return b


def _lowpass_sos(data: GapData):
    s = data.settings
    return signal.butter(s.lowpass_order, s.lowpass_Hz, fs=data.fs_sim_Hz, output="sos")


NOMINAL = Candidate(())


def candidate(*effects: Effect) -> Candidate:
    """The model family with these effects (none: the nominal model)."""
    return Candidate(tuple(Effect(e) for e in effects if Effect(e) is not Effect.NONE))


@dataclass(frozen=True)
class FinalContext:
    """What an effect's :meth:`FittedForm.final` may use of the final (all-trial) fit.

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


#: The base of every effect's fitted form (defined with the effect).
EffectForm = FittedForm


class _Forms(Mapping):
    """Effect -> its fitted form, in the registry's order of physics (follows
    :func:`nmsid.protocols.effects.register`)."""

    def __getitem__(self, e: Effect | str) -> FittedForm:
        try:
            return spec(e).source.form
        except EffectParamError:
            raise KeyError(e) from None

    def __iter__(self) -> Iterator[Effect]:
        return iter(CANDIDATES)

    def __len__(self) -> int:
        return len(CANDIDATES)


#: Effect -> its form (every candidate has one: each effect module defines it).
FORMS: Mapping[Effect, FittedForm] = _Forms()
