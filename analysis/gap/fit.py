"""Fit a model (nominal or augmented) to a set of trials: continuous-time output error.

All sE levels are fitted jointly, because the augmentation's parameters are shared by
them: the unknowns are ``log wn`` and ``log zeta`` per level plus the shared parameters;
``Kp`` per level and the per-trial nuisance terms (offset, trend, smooth baseline) are
solved in closed form inside the residual (variable projection). Levenberg-Marquardt gets
a Jacobian by grouped finite differences: one perturbation moves the ``wn`` of every level
at once (levels do not share residual rows), so a Jacobian costs ``3 + n_shared`` model
runs instead of ``2 n_levels + n_shared``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.signal import lfilter

from nmsid.analysis.damped_lstsq import Damping, levenberg_marquardt
from nmsid.analysis.gap.data import GapData
from nmsid.analysis.gap.harmonics import levy_second_order, local_harmonics
from nmsid.analysis.gap.models import Candidate, nuisance_basis
from nmsid.analysis.gap.samples import effective_fraction
from nmsid.analysis.parameters import Parameters
from nmsid.protocols.effects import Effect

log = logging.getLogger(__name__)

_FD_STEP = 1e-4


@dataclass
class ModelFit:
    """A fitted model: per-level parameters (indexed like ``GapData.sE_levels``) and the
    shared parameters of its augmentation."""

    candidate: Candidate
    p_shared: np.ndarray
    Kp: np.ndarray
    wn_rad_s: np.ndarray
    zeta: np.ndarray
    corner_Hz: float = 0.0
    """Baseline bandwidth of the nuisance model (0: offset and linear trend only)."""
    rss: float = float("nan")
    n_samples: int = 0
    fitted_levels: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    converged: bool = True
    n_steps: int = 0
    """Baseline steps found (``baseline_drift``: a jump at an unknown time in a trial)."""

    @property
    def effect(self) -> Effect:
        return self.candidate.effect

    @property
    def params(self) -> Parameters:
        """The candidate's physical parameters (:meth:`Candidate.params`), with the
        baseline's ``corner_Hz`` when the candidate fits one."""
        out = self.candidate.params(self.p_shared)
        if self.candidate.fits_baseline:
            return Parameters.of({**out, "corner_Hz": self.corner_Hz})
        return out


class Problem:
    """A candidate on a set of trials: simulation, projection and residuals."""

    def __init__(self, data: GapData, cand: Candidate, corner_Hz: float = 0.0):
        self.data = data
        self.cand = cand
        self.Q = nuisance_basis(data.t_eval_s, corner_Hz)
        self.corner_Hz = corner_Hz
        lev = data.level
        self.levels = np.unique(lev)
        self.rows = [np.flatnonzero(lev == j) for j in self.levels]
        self.row_level = np.searchsorted(self.levels, lev)
        """Row -> index into ``self.levels``."""
        self._drive_key: bytes | None = None
        self._drive: np.ndarray | None = None
        # a Jacobian moves one group of parameters at a time: the difference equations
        # depend only on wn, zeta and the dynamics' parameters, the drive only on the
        # drive's, the filtered response on both (the gain is applied after): each is kept
        # for its own parameters (exact: the same inputs give the same arrays)
        self._tfs_cache: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        self._x_cache: dict[tuple[bytes, bytes], np.ndarray] = {}
        self.steps: tuple[BaselineStep, ...] = ()
        """Each row's baseline step (unit column orthogonal to ``Q``) projected out of it."""
        self.yp = self.project(data.y_N)
        self.dt = 1.0 / data.fs_sim_Hz
        self.n_eval = data.y_N.shape[1]

    def project(self, v: np.ndarray) -> np.ndarray:
        """Remove the nuisance columns (and each row's baseline step, if any)."""
        out = v - (v @ self.Q) @ self.Q.T
        for st in self.steps:
            out[st.row] -= (out[st.row] @ st.column) * st.column
        return out

    def set_steps(self, resid: np.ndarray) -> None:
        """Find each row's baseline step in a residual and project it out from now on."""
        self.steps = find_steps(resid, self.Q, self.data)
        self.yp = self.project(self.data.y_N)

    def unit_response(self, wn: np.ndarray, zeta: np.ndarray, p: np.ndarray,
                      drive: np.ndarray | None = None) -> np.ndarray:
        """(n_trials, n_eval) unit-gain response, gain factor applied. ``wn``/``zeta`` are
        indexed like ``self.levels``."""
        d = self.data
        wn = np.asarray(wn, float)
        zeta = np.asarray(zeta, float)
        tkey = wn.tobytes() + zeta.tobytes() + self._key(p, Candidate.DYNAMICS_SLOTS, False)
        if drive is None:
            u = self.drive(p)
            xkey: tuple[bytes, bytes] | None = (tkey, self._drive_key or b"")
        else:
            u, xkey = drive, None
        x = self._x_cache.get(xkey) if xkey is not None else None
        if x is None:
            tfs = self._tfs_cache.get(tkey)
            if tfs is None:
                tfs = self.cand.level_tfs(wn, zeta, p, self.dt)
                _keep(self._tfs_cache, tkey, tfs)
            bs, as_ = tfs
            x = np.empty_like(d.y_N)
            i0, st = d.n_lead_sim, d.sim_step
            for k, rows in enumerate(self.rows):
                out = lfilter(bs[k], as_[k], u[rows])
                x[rows] = out[:, i0::st][:, :self.n_eval]
            if xkey is not None:
                x.flags.writeable = False        # shared by later calls: never edited
                _keep(self._x_cache, xkey, x)
        g = self.cand.gain(d, p)
        return x if g is None else x * g

    def _key(self, p: np.ndarray, slots: tuple[str, ...], timing: bool) -> bytes:
        """The entries of ``p`` that the effects at ``slots`` (and, with ``timing``, the
        timing correction) read, as a cache key."""
        p = np.asarray(p, float)
        idx = [i for i in self.cand.indices_at(slots, timing) if i < p.size]
        return p[idx].tobytes() + p.size.to_bytes(2, "little")

    def residual(self, wn, zeta, p, drive=None) -> tuple[np.ndarray, np.ndarray]:
        """Projected residual (n_trials, n_eval) and the closed-form ``Kp`` per level."""
        xp = self.project(self.unit_response(wn, zeta, p, drive))
        n = len(self.levels)
        den = np.bincount(self.row_level, np.einsum("ij,ij->i", xp, xp), minlength=n)
        num = np.bincount(self.row_level, np.einsum("ij,ij->i", xp, self.yp), minlength=n)
        Kp = np.divide(num, den, out=np.zeros(n), where=den > 0)
        return self.yp - Kp[self.row_level][:, None] * xp, Kp

    def drive(self, p: np.ndarray) -> np.ndarray:
        """The candidate's drive for ``p``, kept for the latest ``p``: the per-level
        perturbations of a Jacobian (``wn``, ``zeta``) reuse it unchanged."""
        key = self._key(p, Candidate.DRIVE_SLOTS, True)
        if key != self._drive_key or self._drive is None:
            self._drive = self.cand.drive(self.data, p)
            self._drive_key = key
        return self._drive


#: Entries kept per cache of :class:`Problem` (a Jacobian's base point and its perturbations).
_CACHE_SIZE = 4


def _keep(cache: dict, key, value) -> None:
    """Insert into a small cache, dropping its oldest entry beyond ``_CACHE_SIZE``."""
    cache[key] = value
    if len(cache) > _CACHE_SIZE:
        del cache[next(iter(cache))]


#: A step is accepted when its least-squares amplitude is this many standard errors from
#: zero (the search over ~100 step times needs a high bar).
STEP_Z = 6.0


@dataclass(frozen=True)
class BaselineStep:
    """A baseline step found in one row of a residual (:func:`find_steps`).

    Attributes
    ----------
    row : int
        The residual's row (trial).
    column : ndarray
        Unit-norm step column (low-passed like the force, orthogonal to the nuisance
        columns): the step is ``(resid[row] @ column) * column``.
    sample : int
        Sample index (evaluation rate) of the step.
    height_per_unit_N : float
        Step height in N per unit of ``column``'s coefficient.
    """

    row: int
    column: np.ndarray
    sample: int
    height_per_unit_N: float


def find_steps(resid: np.ndarray, Q: np.ndarray, data: GapData, z: float = STEP_Z
               ) -> tuple[BaselineStep, ...]:
    """Per row: the most likely time of a baseline step (every 50 ms, 0.3 s from the ends,
    low-passed like the force), kept when significant against the trial's noise (see
    ``STEP_Z``).

    The noise of a step's amplitude is that of the noise's spectrum at low frequency:
    per-sample variance (steady lead-in) over the effective-sample fraction of the noise.

    Returns
    -------
    tuple of BaselineStep
        At most one per row, in row order.
    """
    n = resid.shape[1]
    fs = data.fs_eval_Hz
    stride = max(1, int(round(0.05 * fs)))
    edge = int(round(0.3 * fs))
    times = np.arange(edge, n - edge, stride)
    if len(times) == 0:
        return ()
    S = (np.arange(n)[None, :] >= times[:, None]).astype(float)
    # a step in the force passes the force's low-pass: so does the step column
    sos = signal.butter(data.settings.lowpass_order, data.settings.lowpass_Hz, fs=fs,
                        output="sos")
    S = signal.sosfiltfilt(sos, S, axis=1)
    S -= (S @ Q) @ Q.T
    norm2 = np.sum(S * S, axis=1)
    keep = norm2 > 1e-9
    S, norm2 = S[keep], norm2[keep]
    proj = resid @ S.T                                # (rows, times)
    stat = proj ** 2 / norm2[None, :]
    if data.steady_N is not None and data.steady_noise_N2 is not None:
        nu = effective_fraction(data.steady_N, fs, data.settings.lowpass_Hz)
        var = np.where(np.isfinite(data.steady_noise_N2), data.steady_noise_N2,
                       np.mean(resid ** 2, axis=1))
    else:
        nu, var = 0.5, np.mean(resid ** 2, axis=1)
    out = []
    for i in range(resid.shape[0]):
        k = int(np.argmax(stat[i]))
        if stat[i, k] > z * z * var[i] / max(nu, 1e-3):
            out.append(BaselineStep(row=i, column=S[k] / np.sqrt(norm2[k]),
                                    sample=int(times[keep][k]),
                                    height_per_unit_N=1.0 / float(np.sqrt(norm2[k]))))
    return tuple(out)


def timing_bounds_ms(data: GapData) -> tuple[float, float]:
    """Bounds of the models' timing correction (ms): the total timing, session estimate
    plus correction, stays within +-``input_timing_max_s``; a timing fixed by the settings
    (hold, smooth, calibrated) is not corrected."""
    t = data.timing
    sig = data.settings.signal
    if t is None or not str(t.source).startswith("estimated"):
        return 0.0, 0.0
    m = sig.input_timing_max_s
    return 1e3 * (-m - t.delay_s), 1e3 * (m - t.delay_s)


def initial_levels(data: GapData) -> tuple[np.ndarray, np.ndarray]:
    """Per-level start (wn, zeta) from a Levy fit of the local transfer function."""
    u = local_harmonics(data.d_eval, data.phase_eval_rad, data.f_inst_Hz, data.t_eval_s)
    yh = local_harmonics(data.y_N, data.phase_eval_rad, data.f_inst_Hz, data.t_eval_s)
    H = yh.amplitude[:, :, 0] / u.amplitude[:, :, 0]
    levels = np.unique(data.level)
    wn = np.zeros(len(levels))
    zeta = np.zeros(len(levels))
    for k, j in enumerate(levels):
        Hj = H[data.level == j].mean(axis=0)
        _, wn[k], zeta[k] = levy_second_order(u.f_Hz, Hj)
    return wn, zeta


def fit_model(data: GapData, cand: Candidate, *, start: ModelFit | None = None,
              corner_Hz: float = 0.0, max_iter: int = 30,
              p_start: np.ndarray | None = None) -> ModelFit:
    """Fit one model to the trials in ``data`` (all of them are training trials).

    Parameters
    ----------
    data : GapData
        The training trials.
    cand : Candidate
        The model family.
    start : ModelFit, optional
        A fit whose per-level ``wn``/``zeta`` start this one (same levels); otherwise a
        frequency-domain (Levy) estimate does.
    p_start : ndarray, optional
        Start of the shared parameters (default: the best point of the candidate's grid).
    corner_Hz : float
        Baseline bandwidth of the nuisance model (``baseline_drift`` only).
    max_iter : int
        Levenberg-Marquardt iterations at most.
    """
    prob = Problem(data, cand, corner_Hz)
    nL = len(prob.levels)
    if start is not None and np.array_equal(start.fitted_levels, prob.levels):
        wn0, z0 = start.wn_rad_s[prob.levels].copy(), start.zeta[prob.levels].copy()
    else:
        wn0, z0 = initial_levels(data)
    ns = cand.n_free()
    # screen the shared parameters' starting grid with the per-level start held fixed
    grid = cand.start_grid()
    if p_start is not None:
        p0 = np.asarray(p_start, float)
    elif ns and len(grid) > 1:
        costs = [float(np.sum(prob.residual(wn0, z0, g)[0] ** 2)) for g in grid]
        p0 = grid[int(np.argmin(costs))]
    else:
        p0 = grid[0]
    x0 = np.concatenate([np.log(wn0), np.log(z0), p0])

    def split(x):
        return np.exp(x[:nL]), np.exp(x[nL:2 * nL]), x[2 * nL:]

    def fun(x):
        return prob.residual(*split(x))[0]

    lo_s, hi_s = cand.bounds()
    lo_s[-1], hi_s[-1] = timing_bounds_ms(data)
    lo = np.concatenate([np.full(nL, np.log(3.0)), np.full(nL, np.log(0.03)), lo_s])
    hi = np.concatenate([np.full(nL, np.log(600.0)), np.full(nL, np.log(10.0)), hi_s])
    x0 = np.clip(x0, lo, hi)
    if cand.fits_baseline:
        # steps are found on the starting model's residual and kept during the search
        prob.set_steps(fun(x0))
    x, converged = _levenberg_marquardt(fun, x0, prob.rows, nL, ns, lo, hi,
                                        max_iter=max_iter)
    wn, zeta, p = split(x)
    r, Kp = prob.residual(wn, zeta, p)
    L = len(data.sE_levels)
    full = (np.full(L, np.nan), np.full(L, np.nan), np.full(L, np.nan))
    for arr, val in zip(full, (Kp, wn, zeta), strict=True):
        arr[prob.levels] = val
    return ModelFit(candidate=cand, p_shared=p, Kp=full[0], wn_rad_s=full[1], zeta=full[2],
                    corner_Hz=corner_Hz, rss=float(np.sum(r ** 2)), n_samples=r.size,
                    fitted_levels=prob.levels.copy(), converged=converged,
                    n_steps=len(prob.steps))


def _normal_equations(fun, x, r0, rows, nL, ns):
    """``J^T J`` and ``J^T r`` by grouped forward differences, never forming ``J``."""
    P = x.size
    H = np.zeros((P, P))
    g = np.zeros(P)
    D = []
    for block in range(2):
        xs = x.copy()
        xs[block * nL:(block + 1) * nL] += _FD_STEP
        D.append((fun(xs) - r0) / _FD_STEP)
    S = []
    for m in range(ns):
        xs = x.copy()
        xs[2 * nL + m] += _FD_STEP
        S.append((fun(xs) - r0) / _FD_STEP)
    # every product is a per-row sum first, then summed per level (levels own rows)
    row_level = np.empty(r0.shape[0], dtype=int)
    for k, rws in enumerate(rows):
        row_level[rws] = k

    def per_level(u, v):
        return np.bincount(row_level, np.einsum("ij,ij->i", u, v), minlength=nL)

    for a in range(2):
        sa = slice(a * nL, (a + 1) * nL)
        g[sa] = per_level(D[a], r0)
        for b in range(a, 2):
            sb = slice(b * nL, (b + 1) * nL)
            H[sa, sb] = H[sb, sa] = np.diag(per_level(D[a], D[b]))
        for m in range(ns):
            H[sa, 2 * nL + m] = H[2 * nL + m, sa] = per_level(D[a], S[m])
    for m in range(ns):
        g[2 * nL + m] = np.sum(S[m] * r0)
        for m2 in range(m, ns):
            H[2 * nL + m, 2 * nL + m2] = H[2 * nL + m2, 2 * nL + m] = np.sum(S[m] * S[m2])
    return H, g


def _levenberg_marquardt(fun, x0, rows, nL, ns, lo, hi, *, max_iter=30, rtol=1e-7):
    """Minimise ``sum(fun(x)**2)`` within [lo, hi] with the analysis's one damped solver
    (:func:`nmsid.analysis.damped_lstsq.levenberg_marquardt`) on grouped forward-difference
    normal equations (:func:`_normal_equations`)."""

    def evaluate(x):
        r = fun(x)
        return float(np.sum(r ** 2)), r

    res = levenberg_marquardt(
        evaluate, lambda x, r: _normal_equations(fun, x, r, rows, nL, ns), x0, lo=lo, hi=hi,
        max_iter=max_iter,
        damping=Damping(start=1e-3, up=8.0, up_singular=10.0, down=5.0, floor=1e-9,
                        ceiling=1e10, step_tol=1e-7, rel_tol=rtol, relative_to="before",
                        zero_diag=1.0))
    # no descent direction left counts as a minimum (to the differences' accuracy)
    return res.x, res.converged


def predict(fit: ModelFit, data: GapData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply a fitted model to (held-out) trials.

    Only the per-trial nuisance terms (offset, trend and, for ``baseline_drift``, the
    smooth baseline) are estimated on these trials; the dynamics come from ``fit``.

    Returns
    -------
    residual, prediction, centred : (n_trials, n_eval) ndarray
        Projected residual, model prediction (with the trial's nuisance terms added back),
        and the measured force with offset and linear trend removed (the NRMSE reference).
    """
    prob = Problem(data, fit.candidate, fit.corner_Hz)
    lev = prob.levels
    if np.any(np.isnan(fit.wn_rad_s[lev])):
        missing = [float(data.sE_levels[j]) for j in lev if np.isnan(fit.wn_rad_s[j])]
        raise ValueError(f"no training trials for sE {missing}")
    x = prob.unit_response(fit.wn_rad_s[lev], fit.zeta[lev], fit.p_shared)
    Kp_rows = fit.Kp[data.level][:, None]
    model = Kp_rows * x
    r = prob.project(data.y_N - model)
    if fit.candidate.fits_baseline:
        # a held-out trial's own baseline step is found like its offset: folds keep it
        prob.steps = find_steps(r, prob.Q, data)
        r = prob.project(data.y_N - model)
    pred = data.y_N - r
    ref = Problem(data, fit.candidate, 0.0).project(data.y_N)
    return r, pred, ref
