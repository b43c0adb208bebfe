"""Fitting the physiological twin to a session: every sE level at once, one parameter set.

The data are the gap diagnosis's (:class:`nmsid.analysis.gap.data.GapData`): the identification's
filters, input timing and evaluation grid, and only the trials quality control kept. The
model runs at a reduced rate (``fs_fit_Hz``, 100 Hz by default: the input of each step is
the mid-step value, so halving the rate moves no phase) from the commanded rE, and its
force passes the same zero-phase low-pass as the measured force. The per-trial offset and
linear trend are nuisance terms, projected out exactly as in every gap model.

``scipy.optimize.least_squares`` (trust-region reflective, the literature ranges as
bounds, ``x_scale="jac"``) on the fitted scale (logs of the positive parameters) with the
weak literature priors of :mod:`nmsid.analysis.muscle.literature` as extra residual rows,
weighted by the noise per *effective* sample
(:func:`nmsid.analysis.gap.samples.effective_fraction`). The finite-difference Jacobian is
passed as ``jac``: one batched simulation (all perturbations stacked), so an iteration costs
about as much as two model runs.

Uncertainty: the Gauss-Newton covariance at the optimum, ``s^2 / nu (J'J + prior)^-1``
(``s^2`` the residual variance, ``nu`` the effective-sample fraction). A parameter is *not
determined by the data* when the data alone shrink its prior spread by less than half
(posterior sd > 0.5 prior sd), or, for a parameter without prior, when its sd on the log
scale exceeds 0.5 (a factor 1.6), or when it ends at a bound of its literature range.
The singular values of the scaled Jacobian are kept too.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import fft, optimize
from scipy.signal import savgol_coeffs

from nmsid.analysis.gap.data import GapData
from nmsid.analysis.gap.fit import initial_levels
from nmsid.analysis.gap.models import nuisance_basis
from nmsid.analysis.gap.samples import effective_fraction
from nmsid.analysis.muscle import literature as lit
from nmsid.analysis.muscle.dynamics import PARAM_NAMES, simulate_batch
from nmsid.analysis.muscle.errors import MuscleFitError
from nmsid.analysis.parameters import Parameters
from nmsid.analysis.preprocess import lowpass_sos


def chain_response(f_Hz: np.ndarray, fs_raw_Hz: float, sig) -> np.ndarray:
    """Frequency response of the force's filter chain at the raw rate.

    The identification's Savitzky-Golay smoothing (a symmetric FIR: a real response) and
    its Butterworth low-pass (squared magnitude when run forwards and backwards), as
    :func:`nmsid.analysis.preprocess.smooth_and_lowpass` applies them to the measured force.

    Parameters
    ----------
    f_Hz : ndarray
        Frequencies, Hz.
    fs_raw_Hz : float
        The session's sampling rate.
    sig : IdentificationSettings
        ``savgol_window``, ``savgol_order``, ``lowpass_Hz``, ``butter_order``, ``zero_phase``.

    Returns
    -------
    ndarray (complex)

    Examples
    --------
    >>> from nmsid.analysis.preprocess import IdentificationSettings
    >>> H = chain_response(np.array([0.0, 10.0]), 1000.0, IdentificationSettings())
    >>> bool(abs(H[0] - 1) < 1e-9 and 0.98 < H[1].real < 0.999)
    True
    """
    f = np.asarray(f_Hz, float)
    H = np.ones(f.shape, complex)
    if sig.savgol_window is not None:
        taps = savgol_coeffs(sig.savgol_window, sig.savgol_order)
        half = sig.savgol_window // 2
        k = np.arange(len(taps)) - half
        H = H * (np.cos(2 * np.pi * np.outer(f, k) / fs_raw_Hz) @ taps)
    sos = lowpass_sos(fs_raw_Hz, sig)
    if sos is not None:
        hb = sos_response(sos, f, fs_raw_Hz)
        H = H * (np.abs(hb) ** 2 if sig.zero_phase else hb)
    return H


def sos_response(sos: np.ndarray, f_Hz: np.ndarray, fs_Hz: float) -> np.ndarray:
    """Frequency response of second-order sections at ``f_Hz`` (``scipy.signal.sosfreqz``
    with ``worN=f_Hz, fs=fs_Hz``, equal to rounding; without importing scipy.signal, whose
    import costs more than the muscle twin's set-up).

    Examples
    --------
    >>> import numpy as np
    >>> sos = np.array([[0.5, 0.5, 0.0, 1.0, 0.0, 0.0]])        # a two-tap average
    >>> np.round(sos_response(sos, np.array([0.0, 250.0]), 1000.0), 6).tolist()
    [(1+0j), (0.5-0.5j)]
    """
    zi = np.exp(-2j * np.pi * np.asarray(f_Hz, float) / fs_Hz)      # z^-1
    h = np.ones(zi.shape, complex)
    for b0, b1, b2, a0, a1, a2 in np.asarray(sos, float):
        h = h * ((b0 + zi * (b1 + zi * b2)) / (a0 + zi * (a1 + zi * a2)))
    return h


@dataclass(frozen=True)
class MuscleFitSettings:
    """How the physiological twin is fitted (see module)."""

    fs_fit_Hz: float = 100.0
    """Simulation rate of the fit; must divide the gap data's simulation rate."""
    trial_gain: tuple[float, ...] | None = None
    """Each trial's gain relative to the session's mean (the session's fatigue,
    :meth:`nmsid.analysis.fatigue.FatigueResult.gain_at` at the trial): the model's force
    of trial ``i`` is multiplied by it, so that one muscle parameter set is fitted to a
    fatiguing session. None (or a length other than the data's trials): 1 for every
    trial."""
    max_iter: int = 40
    """At most this many Jacobians (least_squares' ``max_nfev`` is twice it)."""
    rtol: float = 1e-3
    """Stop when the objective improves by less than this fraction (``ftol``). 1e-3
    rather than 2e-4 halves the fit on the slowest sessions of ``bench_muscle`` (its
    slow tail) for +0.6 % of the held-out NRMSE on HILL (2.505 -> 2.520 %) and +28 % on
    DEGROOTE2016-B (2.80 -> 3.57 %, a plateau the longer fit leaves late; 4e-4 does not),
    the other eight within 0.1 %."""
    progress: bool = False
    """Write one line per iteration to stderr."""


@dataclass
class MuscleFit:
    """One fitted physiological twin."""

    theta: np.ndarray
    """Physical parameters, :data:`~nmsid.analysis.muscle.dynamics.PARAM_NAMES` order."""
    rss: float
    n_samples: int
    nrmse_pct: float
    sd_z: np.ndarray
    """Standard deviation of each parameter on the fitted scale (log for positive ones)."""
    determined: np.ndarray
    """(14,) bool: the data determine the parameter (see module; one held at its bound
    is not determined)."""
    singular_values: np.ndarray
    iterations: int
    elapsed_s: float
    history: list = field(default_factory=list)
    z: np.ndarray | None = None
    """The optimum on the fitted scale."""
    jac: np.ndarray | None = None
    """Jacobian of the weighted residual (trial-major data rows, then the prior rows) at
    the optimum, on the fitted scale: the linearisation :func:`subset_step` uses."""
    fun: np.ndarray | None = None
    """The weighted residual at the optimum (the rows of ``jac``)."""
    resid_shape: tuple[int, int] = (0, 0)
    """(n_trials, n_eval) of the data rows of ``jac`` and ``fun``."""

    @property
    def params(self) -> Parameters:
        """The fitted parameters by name (``PARAM_NAMES`` order)."""
        return Parameters(tuple((n, float(v))
                                for n, v in zip(PARAM_NAMES, self.theta, strict=True)))

    def table(self) -> list[dict]:
        """Each parameter with its uncertainty (relative for the log-scale ones)."""
        rows = []
        for k, n in enumerate(PARAM_NAMES):
            row = {"name": n, "value": float(self.theta[k]),
                   "determined": bool(self.determined[k])}
            if lit.LOG[k]:
                row["sd_rel_pct"] = 100.0 * float(np.expm1(self.sd_z[k]))
            else:
                row["sd"] = float(self.sd_z[k])
            rows.append(row)
        return rows


class _Problem:
    """The residual of one set of trials, for stacked parameter sets."""

    def __init__(self, data: GapData, s: MuscleFitSettings):
        dec = int(round(data.fs_sim_Hz / s.fs_fit_Hz))
        if dec < 1 or abs(data.fs_sim_Hz / dec - s.fs_fit_Hz) > 1e-6 or data.sim_step % dec:
            raise MuscleFitError(
                f"fs_fit_Hz = {s.fs_fit_Hz:g}: the muscle twin's fit rate must divide the "
                f"simulation rate {data.fs_sim_Hz:g} Hz and leave the {data.fs_eval_Hz:g} Hz "
                "evaluation grid on its samples (e.g. 100 or 200)")
        self.dec = dec
        self.dt_s = dec / data.fs_sim_Hz
        # mid-step input: the mean of the commanded rE over each fit step
        rE = data.rE_sim
        n = (rE.shape[1] // dec) * dec
        self.rE = rE[:, :n].reshape(rE.shape[0], -1, dec).mean(axis=2)
        self.sE = np.array([t.sE for t in data.trials])
        # repeats of one sE with the same commanded rE have the same model response:
        # each distinct (sE, rE) is simulated once (a 45-trial session: 15 simulations)
        keys: dict[tuple[float, bytes], int] = {}
        self.inverse = np.array([keys.setdefault((float(sv), r.tobytes()), len(keys))
                                 for sv, r in zip(self.sE, self.rE, strict=True)])
        first = np.unique(self.inverse, return_index=True)[1]
        self.rE_u, self.sE_u = self.rE[first], self.sE[first]
        self.idx = (data.n_lead_sim + np.arange(data.y_N.shape[1]) * data.sim_step) // dec
        if self.idx[-1] >= self.rE.shape[1]:
            self.idx = self.idx[self.idx < self.rE.shape[1]]
        self.y = data.y_N[:, : len(self.idx)]
        g = s.trial_gain
        self.gain = np.asarray(g, float) if g is not None and len(g) == data.y_N.shape[0] \
            else None
        self.Q = nuisance_basis(data.t_eval_s[: len(self.idx)], 0.0)
        # the measured force's filter chain (Savitzky-Golay and low-pass at the raw rate),
        # applied to the model's force by its exact frequency response at the fit rate:
        # a Butterworth redesigned at the fit rate would differ by 1 % at 10 Hz
        T = self.rE.shape[1]
        self.pad = min(T - 1, int(round(s.fs_fit_Hz)))       # 1 s, odd reflection
        self.n_fft = int(fft.next_fast_len(T + 2 * self.pad, real=True))
        self.f_Hz = np.fft.rfftfreq(self.n_fft, self.dt_s)
        self.H = chain_response(self.f_Hz, data.fs_raw_Hz, data.settings.signal)
        self.ref = self._project(self.y)

    def _project(self, v):
        return v - (v @ self.Q) @ self.Q.T

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """(P, n_trials, n_eval) filtered force at the evaluation samples."""
        th = np.atleast_2d(theta)
        x = simulate_batch(th, self.rE_u, self.sE_u, self.dt_s)
        x = self.filter(x, th[:, PARAM_NAMES.index("delay_s")])
        x = x[:, self.inverse][..., self.idx]
        return x * self.gain[None, :, None] if self.gain is not None else x

    def filter(self, x: np.ndarray, delay_s: np.ndarray) -> np.ndarray:
        """The measured force's filter chain (``self.H``) and each parameter set's delay
        (an exact band-limited time shift) along the last axis of ``x`` (P, n, T)."""
        p, T = self.pad, x.shape[-1]
        a, b = x[..., :1], x[..., -1:]
        xp = np.concatenate([2 * a - x[..., p:0:-1], x, 2 * b - x[..., -2:-p - 2:-1]],
                            axis=-1)
        shift = np.exp(-2j * np.pi * np.outer(delay_s, self.f_Hz))[:, None, :]
        y = fft.irfft(fft.rfft(xp, n=self.n_fft, axis=-1) * (self.H * shift), n=self.n_fft,
                      axis=-1)
        return y[..., p:p + T]

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """(P, n_trials, n_eval) measured minus predicted, offset and trend removed."""
        return self._project(self.y[None] - self.predict(theta))


def _noise_scale(data: GapData) -> tuple[float, float]:
    """(noise variance per sample, effective-sample fraction nu) from the steady lead-in."""
    bw = data.settings.lowpass_Hz
    if data.steady_N is not None and data.steady_N.shape[1] >= 16:
        nu = effective_fraction(data.steady_N, data.fs_eval_Hz, bw)
    else:
        nu = min(1.0, 2 * bw / data.fs_eval_Hz)
    s2 = float(np.nanmean(data.steady_noise_N2)) if data.steady_noise_N2 is not None else np.nan
    return (s2 if np.isfinite(s2) and s2 > 0 else np.nan), float(nu)


def initial_theta(data: GapData) -> np.ndarray:
    """Literature values with the forces and the mount's wn, zeta scaled to the session."""
    th = lit.start_theta()
    try:
        wn, zeta = initial_levels(data)
        th[PARAM_NAMES.index("wn0_rad_s")] = float(np.clip(np.min(wn) * 0.9, 5.0, 200.0))
        th[PARAM_NAMES.index("zeta0")] = float(np.clip(np.min(zeta), 0.05, 2.0))
    except (ValueError, np.linalg.LinAlgError):
        pass
    prob = _Problem(data, MuscleFitSettings())
    pred = prob._project(prob.predict(th)[0])
    g = float(np.sum(pred * prob.ref) / max(np.sum(pred ** 2), 1e-30))
    if g > 0:
        th[0] *= g
        th[1] *= g
    return th


def fit_muscle(data: GapData, settings: MuscleFitSettings | None = None, *,
               start: np.ndarray | None = None, label: str = "") -> MuscleFit:
    """Fit the physiological twin to the trials of ``data`` (all sE levels at once).

    Parameters
    ----------
    data : GapData
        Pre-processed session (or a fold's training trials).
    settings : MuscleFitSettings, optional
    start : ndarray, optional
        Physical starting parameters (default: :func:`initial_theta`).
    label : str
        Shown in the progress line.

    Returns
    -------
    MuscleFit

    Raises
    ------
    MuscleFitError
        The fit rate does not suit the data.
    """
    s = settings or MuscleFitSettings()
    t0 = time.perf_counter()
    prob = _Problem(data, s)
    s2, nu = _noise_scale(data)
    if not np.isfinite(s2):
        s2 = 1e-4 * float(np.mean(prob.ref ** 2))
    # prior rows: (z - z0) / sd, in units of the noise per effective sample
    w_prior = np.sqrt(s2 / nu)
    has_prior = np.isfinite(lit.PRIOR_SD)
    z0 = lit.prior_centre_z()
    lo, hi = lit.bounds_z()
    z = np.clip(lit.to_z(start if start is not None else initial_theta(data)), lo, hi)
    n_p = len(z)
    steps = np.full(n_p, 1e-4)

    def cost_parts(z_rows):
        with np.errstate(over="ignore", invalid="ignore"):
            r = prob.residuals(lit.to_theta(z_rows)).reshape(len(z_rows), -1)
        # a trial step into an unstable corner (huge damping at the fit rate) diverges:
        # a large finite residual makes the solver reject it instead of failing on NaN
        r = np.where(np.isfinite(r), np.clip(r, -1e6, 1e6), 1e6)
        pr = w_prior * (z_rows[:, has_prior] - z0[has_prior]) / lit.PRIOR_SD[has_prior]
        return np.concatenate([r, pr], axis=1)

    hist: list[float] = []
    ref2 = float(np.sum(prob.ref ** 2))
    span = hi - lo
    z = np.clip(z, lo + 1e-9 * span, hi - 1e-9 * span)    # strictly inside for TRF
    njev = [0]

    def fun(zv):
        r = cost_parts(zv[None])[0]
        nrmse = 100.0 * float(np.sqrt(max(float(r @ r), 0.0) / ref2))
        hist.append(nrmse)
        if s.progress:
            print(f"\rmuscle twin{(' ' + label) if label else ''}: evaluation {len(hist)}, "
                  f"NRMSE {nrmse:.3f} %, {time.perf_counter() - t0:.0f} s   ",
                  end="", file=sys.stderr, flush=True)
        return r

    def jac(zv):
        # forward differences, stepping away from a bound, in one batched simulation
        njev[0] += 1
        h = np.where(zv + steps <= hi, steps, -steps)
        R = cost_parts(np.vstack([zv] + [zv + h[k] * np.eye(n_p)[k] for k in range(n_p)]))
        return ((R[1:] - R[0]) / h[:, None]).T

    res = optimize.least_squares(fun, z, jac=jac, bounds=(lo, hi), method="trf",
                                 x_scale="jac", ftol=s.rtol, xtol=1e-8, gtol=1e-10,
                                 max_nfev=2 * s.max_iter)
    z = res.x
    J = res.jac
    it = njev[0]
    if s.progress:
        print(file=sys.stderr, flush=True)
    rd = prob.residuals(lit.to_theta(z[None]))[0]
    rss = float(np.sum(rd ** 2))
    n = rd.size
    # uncertainty at the optimum (J from the last accepted linearisation)
    Jd = J[:n] if J is not None else np.zeros((n, n_p))
    s2_res = rss / n
    A_data = Jd.T @ Jd * nu / s2_res
    A_prior = np.diag(np.where(has_prior, 1.0 / np.where(has_prior, lit.PRIOR_SD, 1.0) ** 2,
                               0.0))
    cov = np.linalg.pinv(A_data + A_prior)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    determined = np.where(has_prior, sd < 0.5 * np.where(has_prior, lit.PRIOR_SD, 1.0),
                          sd < 0.5)
    at_bound = (z <= lo + 1e-6 * span) | (z >= hi - 1e-6 * span)
    determined &= ~at_bound     # a parameter held by its bound is not the data's answer
    D = np.sqrt(np.maximum(np.diag(A_data), 1e-300))
    sv = np.linalg.svd(A_data / np.outer(D, D), compute_uv=False)
    return MuscleFit(theta=lit.to_theta(z), rss=rss, n_samples=n,
                     nrmse_pct=100.0 * np.sqrt(rss / np.sum(prob.ref ** 2)), sd_z=sd,
                     determined=determined, singular_values=sv, iterations=it,
                     elapsed_s=time.perf_counter() - t0, history=hist, z=z, jac=J,
                     fun=np.asarray(res.fun), resid_shape=rd.shape)


@dataclass
class FoldStep:
    """The twin refitted on a subset of the trials by one Gauss-Newton step."""

    theta: np.ndarray
    """Physical parameters after the step."""
    rss: float
    """Residual sum of squares on the subset's trials (offset and trend removed)."""
    n_samples: int
    elapsed_s: float


#: Levenberg damping factors tried by :func:`subset_refit` (relative to diag(J'J)).
SUBSET_DAMPING = (0.0, 1e-3, 1e-2, 0.1, 1.0)


def subset_refit(full: MuscleFit, data: GapData, subsets: list[np.ndarray],
                 settings: MuscleFitSettings | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Parameters refitted on each subset of the trials, and their residuals on every trial.

    From the optimum of all trials, for each subset a Levenberg-Marquardt step of the
    subset's rows (its trials and the priors) is formed with the Jacobian of the full fit
    for each damping of :data:`SUBSET_DAMPING`; all of them, and the full fit itself,
    are simulated in one batch, and each subset keeps the one with the lowest cost on
    *its own* trials (the left-out trials play no part in the choice). The influence of
    the left-out trials is so removed to first order at the cost of one Jacobian's worth
    of simulation; ``docs/muscle-twin.md`` compares it with full refits.

    Parameters
    ----------
    full : MuscleFit
        Fit on every trial of ``data`` (with its Jacobian).
    data : GapData
        The data ``full`` was fitted on.
    subsets : list of ndarray of int
        The trials (rows of ``data``) of each subset.
    settings : MuscleFitSettings, optional

    Returns
    -------
    thetas : ndarray, (n_subsets, n_params)
        Physical parameters of each subset's twin.
    resid : ndarray, (n_subsets, n_trials, n_eval')
        Their residuals on every trial (offset and trend removed).
    """
    if full.jac is None or full.fun is None or full.z is None:
        raise ValueError("subset_refit needs a fit with its Jacobian (fit_muscle's result)")
    n_tr, n_ev = full.resid_shape
    n_data = n_tr * n_ev
    lo, hi = lit.bounds_z()
    span = hi - lo
    zs = [full.z]
    for keep in subsets:
        rows = np.ones(full.fun.size, bool)
        sel = np.zeros(n_tr, bool)
        sel[keep] = True
        rows[:n_data] = np.repeat(sel, n_ev)
        J, c = full.jac[rows], full.fun[rows]
        A, g = J.T @ J, J.T @ c
        dA = np.diag(np.maximum(np.diag(A), 1e-300))
        for lam in SUBSET_DAMPING:
            dz = -np.linalg.lstsq(A + lam * dA, g, rcond=1e-12)[0]
            zs.append(np.clip(full.z + dz, lo + 1e-9 * span, hi - 1e-9 * span))
    Z = np.vstack(zs)
    R = residual_matrix(lit.to_theta(Z), data, settings)
    prior_rows = full.fun[n_data:]
    has_prior = np.isfinite(lit.PRIOR_SD)
    # the prior rows' weight is the full fit's: recover it from its rows at its optimum
    z0 = lit.prior_centre_z()[has_prior]
    dzp = (full.z[has_prior] - z0) / lit.PRIOR_SD[has_prior]
    w = float(np.sum(prior_rows * dzp) / max(float(np.sum(dzp ** 2)), 1e-300))
    prior_cost = w ** 2 * np.sum(((Z[:, has_prior] - z0) / lit.PRIOR_SD[has_prior]) ** 2,
                                 axis=1)
    n_try = len(SUBSET_DAMPING)
    thetas, resid = [], []
    for k, keep in enumerate(subsets):
        cand = [0] + list(range(1 + k * n_try, 1 + (k + 1) * n_try))
        cost = [float(np.sum(R[i][keep] ** 2)) + prior_cost[i] for i in cand]
        best = cand[int(np.argmin(cost))]
        thetas.append(lit.to_theta(Z[best]))
        resid.append(R[best])
    return np.vstack(thetas), np.stack(resid)


def residual_matrix(theta_rows: np.ndarray, data: GapData,
                    settings: MuscleFitSettings | None = None) -> np.ndarray:
    """(P, n_trials, n_eval') residual of each parameter set on ``data`` (offset and trend
    removed), one batched simulation; ``n_eval'`` stops at the fit grid's last sample."""
    prob = _Problem(data, settings or MuscleFitSettings())
    with np.errstate(over="ignore", invalid="ignore"):
        return prob.residuals(np.atleast_2d(theta_rows))

