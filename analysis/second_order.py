"""Continuous-time output-error fit of G(s) = Kp wn^2 / (s^2 + 2 zeta wn s + wn^2).

What MATLAB's ``tfest`` does for this model, done in closed form where possible:

1. a start from simplified refined instrumental variables (:mod:`nmsid.analysis.initial_estimate`);
2. prediction-error minimisation of ||y - yhat||^2 (output error: the model is simulated
   from the input alone), with the initial state, an output offset and (by default) an
   output ramp estimated along with Kp, wn and zeta.

The model output is linear in Kp, the initial state (as the first two free-response
samples), offset and ramp, so those are solved exactly by least squares for every (wn,
zeta) - variable projection (Golub & Pereyra 2003; Kaufman's Jacobian) - and a
Levenberg-Marquardt search runs over ln wn and ln zeta only. The simulation is the exact
triangle-hold discretisation run by ``lfilter`` (:mod:`nmsid.analysis.discretize`); its
sensitivities are obtained by filtering too (derivatives of the difference equation), so
one iteration costs a handful of ``lfilter`` passes and no ``lsim``.

Standard errors come from the Jacobian at the optimum, scaled by the noise level of the
residual (see :class:`nmsid.analysis.settings.NoiseLevel`). They assume the model structure is
right and the noise is stationary; the effective number of independent samples is not the
number of samples once the data are low-passed, which is why the default noise level is
the residual PSD over the chirp band rather than RSS/(N - p).
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from nmsid.analysis.damped_lstsq import Damping, levenberg_marquardt
from nmsid.analysis.discretize import foh_coefficients_with_derivatives, smooth_hold_input
from nmsid.analysis.errors import IdentificationError
from nmsid.analysis.initial_estimate import StartEstimate, srivc_start
from nmsid.analysis.residual_tests import ResidualTests, residual_tests
from nmsid.analysis.settings import IdentificationSettings, InputHold, NoiseLevel
from nmsid.analysis.thin_lstsq import cross, dot, gram, lstsq_rows, orthonormalise
from nmsid.protocols.reprs import html_repr, short_repr

logger = logging.getLogger(__name__)

#: Lower bound of (ln wn, ln zeta) during the search: wn > 1e-3 rad/s, zeta > 1e-3.
_P_LOW = math.log(1e-3)

#: Fewest samples a fit accepts (7 parameters and the residual tests need more).
MIN_SAMPLES = 50


@dataclass
class SecondOrderFit:
    """Result of :func:`fit_second_order`. Units: Kp in N per unit rE, wn in rad/s."""

    Kp: float
    wn_rad_s: float
    zeta: float
    Kp_se: float
    wn_se: float
    zeta_se: float
    fit_pct: float
    """100 (1 - ||y - yhat|| / ||y - mean y||), as MATLAB's ``compare``/``tfest`` report."""
    converged: bool
    message: str
    iterations: int
    t_s: np.ndarray
    y_N: np.ndarray
    """The data that were fitted (preprocessed force)."""
    y_fit_N: np.ndarray
    """Model output: simulated response + free response of the initial state + offset
    (+ ramp)."""
    fs_Hz: float
    offset_N: float
    """Estimated output offset at the window's centre."""
    trend_N_per_s: float
    initial_output_N: tuple[float, float]
    """First two samples of the free (initial-state) response."""
    noise_sd_N: float
    """Standard deviation of the equivalent white noise at ``fs_Hz`` behind the standard
    errors."""
    covariance: np.ndarray
    """Covariance of (Kp, wn_rad_s, zeta)."""
    start: StartEstimate | None = None
    notes: list[str] = field(default_factory=list)
    _tests_of: tuple | None = field(default=None, repr=False, compare=False)
    """(residual, input, lags, confidence) of the residual tests, run on first use."""
    _tests: ResidualTests | None = field(default=None, repr=False, compare=False)

    @property
    def residual_tests(self) -> ResidualTests:
        """Whiteness and input-independence tests of the residual
        (:func:`nmsid.analysis.residual_tests.residual_tests`). Run on first use: the
        per-repeat fits of the scatter never read them."""
        if self._tests is None:
            if self._tests_of is None:
                raise AttributeError("this fit holds no residual to test")
            resid, u, lags, confidence = self._tests_of
            self._tests = residual_tests(resid, u, lags, confidence)
        return self._tests

    def __repr__(self) -> str:
        return short_repr(
            "SecondOrderFit", f"Kp {self.Kp:.4g} +- {self.Kp_se:.2g} N",
            f"wn {self.wn_rad_s:.4g} +- {self.wn_se:.2g} rad/s",
            f"zeta {self.zeta:.4g} +- {self.zeta_se:.2g}", f"fit {self.fit_pct:.1f} %",
            "converged" if self.converged else f"not converged ({self.message})",
            f"{len(self.y_N)} samples at {self.fs_Hz:g} Hz")

    _repr_html_ = html_repr

    @property
    def residual_N(self) -> np.ndarray:
        return self.y_N - self.y_fit_N

    @property
    def n_samples(self) -> int:
        return int(len(self.y_N))


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    out = np.empty_like(x)
    out[:k] = 0.0
    out[k:] = x[:len(x) - k]
    return out


class _Problem:
    """Variable-projection pieces of the output-error problem for fixed data.

    :meth:`evaluate` computes the cost first and the Jacobian only when asked (or later,
    by :meth:`jacobian`, for a trial point the search accepts): a refused step costs one
    filter pass instead of two. The numbers are the same whichever way they are reached.
    """

    def __init__(self, v: np.ndarray, y: np.ndarray, dt_s: float, trend: bool):
        self.v = v
        self.y = y
        self.dt_s = dt_s
        self.n = len(y)
        self.tau = np.linspace(-1.0, 1.0, self.n)
        self.trend = trend
        self.impulse = np.zeros(self.n)
        self.impulse[0] = 1.0
        #: the impulse and the input, filtered together (one filter set-up per evaluation)
        self._stacked = np.vstack([self.impulse, v])
        #: upper bound of (ln wn, ln zeta): wn below 10x the Nyquist frequency, zeta < 1000
        self.p_high = np.array([math.log(10 * math.pi / dt_s), math.log(1000.0)])

    def evaluate(self, p: np.ndarray, jacobian: bool):
        """Cost, linear parameters and (optionally) the full and reduced Jacobians at p.

        Regressors are rows of (m, n) arrays (see :mod:`nmsid.analysis.thin_lstsq`).
        """
        num, den, dnum, dden = foh_coefficients_with_derivatives(p[0], p[1], self.dt_s)
        v = self.v
        # the impulse response and the filtered input in one call (one filter set-up)
        h, w = lfilter([1.0], den, self._stacked)
        h1 = _shift(h, 1)
        s0 = w - v[0] * h - v[1] * h1
        s1 = _shift(w, 1) - v[0] * h1
        s2 = _shift(w, 2)
        basis = np.empty((5 if self.trend else 4, self.n))
        basis[0] = num[0] * s0 + num[1] * s1 + num[2] * s2     # forced response, Kp = 1
        basis[1] = h + den[1] * h1                              # free response, y_0 = 1
        basis[2] = h1                                           # free response, y_1 = 1
        basis[3] = 1.0
        if self.trend:
            basis[4] = self.tau
        coef, q, _ = lstsq_rows(basis, self.y)
        y_fit = coef @ basis
        resid = self.y - y_fit
        out = {"cost": dot(resid, resid), "coef": coef, "y_fit": y_fit, "resid": resid,
               "basis": basis, "_parts": (den, dnum, dden, s0, s1, s2, h1, q)}
        if jacobian:
            self.jacobian(out)
        return out

    def jacobian(self, ev: dict) -> dict:
        """Add the full (``jp``) and reduced (``j_reduced``) Jacobians of (ln wn, ln zeta)
        to an evaluation (once: a second call finds them there)."""
        if "jp" in ev:
            return ev
        den, dnum, dden, s0, s1, s2, h1, q = ev["_parts"]
        coef, basis = ev["coef"], ev["basis"]
        kp, y0, y1 = coef[0], coef[1], coef[2]
        y_dyn = kp * basis[0] + y0 * basis[1] + y1 * h1
        qf = lfilter([1.0], den, y_dyn)
        r1 = _shift(qf, 1) - y0 * h1
        r2 = _shift(qf, 2)
        jp = np.empty((2, self.n))
        for j in range(2):
            jp[j] = (kp * (dnum[j, 0] * s0 + dnum[j, 1] * s1 + dnum[j, 2] * s2)
                     - dden[j, 1] * r1 - dden[j, 2] * r2)
        ev["jp"] = jp
        ev["j_reduced"] = jp - (jp @ q.T) @ q
        return ev


def _levenberg_marquardt(problem: _Problem, p0: np.ndarray, max_iter: int, tol: float):
    """Minimise the projected cost over p = (ln wn, ln zeta) with the analysis's one damped
    solver (:func:`nmsid.analysis.damped_lstsq.levenberg_marquardt`); the open bounds of p
    refuse a step beyond them."""

    def evaluate(p):
        if not np.all((p > _P_LOW) & (p < problem.p_high)):
            return math.inf, None
        ev = problem.evaluate(p, jacobian=False)    # a refused point needs no Jacobian
        return ev["cost"], ev

    def normal(p, ev):
        jr = problem.jacobian(ev)["j_reduced"]     # d(fit)/dp: the residual's Jacobian is -jr
        return gram(jr), -cross(jr, ev["resid"][None, :])[:, 0]

    def at_minimum(a, g, cost):
        # no step lowers the cost: a minimum if a full Gauss-Newton step could not gain
        # more than rounding does
        try:
            gain = float(g @ np.linalg.solve(a, g))
        except np.linalg.LinAlgError:
            gain = math.inf
        return gain <= max(tol, 1e-12) * cost or \
            cost <= 1e-28 * max(dot(problem.y, problem.y), 1e-300)

    p0 = np.array(p0, dtype=float)
    ev0 = problem.evaluate(p0, jacobian=True)      # the start itself is never refused
    res = levenberg_marquardt(
        evaluate, normal, p0, max_iter=max_iter, stalled_converged=at_minimum,
        evaluated=(ev0["cost"], ev0),
        damping=Damping(start=1e-3, up=10.0, down=10.0, floor=1e-12, ceiling=1e12,
                        step_tol=1e-10, rel_tol=tol, rel_step_tol=math.sqrt(tol),
                        relative_to="after", accept_equal=True, up_singular=10.0,
                        zero_diag=1e-300))
    return res.x, res.state, res.converged, res.message, res.iterations


def _noise_variance(resid: np.ndarray, fs_Hz: float, n_params: int, level: NoiseLevel,
                    band_Hz: tuple[float, float] | None) -> float:
    n = len(resid)
    white = float(resid @ resid) / max(n - n_params, 1)
    if level is NoiseLevel.WHITE or n < 64:
        return white
    nperseg = int(min(n, 2 ** int(round(math.log2(max(fs_Hz * 2.0, 64))))))
    f, pxx = _welch(resid, fs_Hz, nperseg)
    lo, hi = band_Hz if band_Hz else (0.0, fs_Hz / 2)
    sel = (f >= lo) & (f <= hi)
    if sel.sum() < 2:
        return white
    return float(np.mean(pxx[sel]) * fs_Hz / 2.0)


@functools.lru_cache(maxsize=8)
def _hann(nperseg: int) -> tuple[np.ndarray, float]:
    """Periodic Hann window (scipy's 'hann') of ``nperseg`` samples and the sum of its
    squares; read-only, made once per length (every fit of a session uses the same)."""
    win = np.hanning(nperseg + 1)[:-1]
    win.flags.writeable = False
    return win, float(np.sum(win ** 2))


def _welch(x: np.ndarray, fs_Hz: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD by Welch's method (Hann window, 50 % overlap, mean removed per
    segment); the same as ``scipy.signal.welch`` defaults, without its overhead."""
    step = nperseg // 2
    starts = range(0, len(x) - nperseg + 1, step)
    win, win_power = _hann(nperseg)
    segs = np.array([x[i:i + nperseg] for i in starts])
    segs = (segs - segs.mean(axis=1, keepdims=True)) * win
    spec = np.abs(np.fft.rfft(segs, axis=1)) ** 2
    pxx = spec.mean(axis=0) / (fs_Hz * win_power)
    pxx[1:-1 if nperseg % 2 == 0 else None] *= 2.0
    return np.fft.rfftfreq(nperseg, 1.0 / fs_Hz), pxx


def _grid_starts(fs_Hz: float) -> list[tuple[float, float]]:
    wn_max = min(2 * math.pi * fs_Hz / 5, 2000.0)
    wns = np.geomspace(1.0, wn_max, 16)
    zetas = (0.05, 0.12, 0.25, 0.45, 0.7, 1.1, 2.0)
    return [(float(w), z) for w in wns for z in zetas]


def fit_second_order(u: np.ndarray, y: np.ndarray, fs_Hz: float,
                     settings: IdentificationSettings | None = None, *,
                     band_Hz: tuple[float, float] | None = None,
                     start: tuple[float, float] | None = None,
                     t0_s: float = 0.0) -> SecondOrderFit:
    """Fit the second-order output-error model from input ``u`` to output ``y``.

    Parameters
    ----------
    u : ndarray
        Input (rE with its window mean removed; dimensionless), uniformly sampled.
    y : ndarray
        Output (force in N), same length.
    fs_Hz : float
        Sampling rate in Hz.
    settings : IdentificationSettings, optional
        Uses ``input_hold``, ``estimate_trend``, ``max_iterations``, ``tolerance``,
        ``retry_below_fit_pct``, ``noise_level``, ``resid_lags``, ``resid_confidence``.
    band_Hz : (float, float), optional
        Band of the excitation (the chirp's f0, f1) for the noise level of the standard
        errors; default the whole band.
    start : (wn_rad_s, zeta), optional
        Starting point; default the instrumental-variable estimate.
    t0_s : float
        Time of the first sample (only stored in the result's ``t_s``).

    Returns
    -------
    SecondOrderFit

    Raises
    ------
    IdentificationError
        If the data are too short, of different lengths, or not finite.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.signal import lsim
    >>> t = np.arange(0, 4, 1e-3)
    >>> u = np.sin(2 * np.pi * (1 + t) * t)
    >>> y = lsim(([5 * 400.0], [1, 2 * 0.3 * 20, 400.0]), u, t)[1]
    >>> s = IdentificationSettings(input_hold="linear", estimate_trend=False)
    >>> f = fit_second_order(u, y, 1000.0, s)
    >>> round(f.Kp, 6), round(f.wn_rad_s, 6), round(f.zeta, 6)
    (5.0, 20.0, 0.3)
    """
    s = settings or IdentificationSettings()
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.shape != y.shape or u.ndim != 1:
        raise IdentificationError(f"input and output must be 1-D of equal length, got "
                                  f"{u.shape} and {y.shape}")
    if len(y) < MIN_SAMPLES:
        raise IdentificationError(f"only {len(y)} samples to fit; need at least {MIN_SAMPLES}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise IdentificationError("input or output contains NaN or infinite samples")
    if not fs_Hz > 0:
        raise IdentificationError(f"fs_Hz = {fs_Hz!r} must be > 0")
    dt = 1.0 / fs_Hz
    v = smooth_hold_input(u) if s.input_hold is InputHold.SMOOTH else u
    problem = _Problem(v, y, dt, s.estimate_trend)
    notes: list[str] = []

    start_est = None
    if start is None:
        start_est = srivc_start(v, y, dt, trend=s.estimate_trend)
        starts = [(start_est.wn_rad_s, start_est.zeta)] if start_est else []
        if not start_est:
            notes.append("instrumental-variable start failed; started from a grid")
    else:
        starts = [(float(start[0]), float(start[1]))]

    def run(wn_z):
        p0 = np.log(np.array(wn_z, dtype=float))
        return _levenberg_marquardt(problem, p0, s.max_iterations, s.tolerance)

    y_var = float(np.sum((y - y.mean()) ** 2))

    def fit_pct(ev):
        return 100.0 * (1.0 - math.sqrt(ev["cost"] / y_var)) if y_var > 0 else float("nan")

    best = run(starts[0]) if starts else None
    if best is None or not best[2] or fit_pct(best[1]) < s.retry_below_fit_pct:
        # look for a better basin: a coarse grid of (wn, zeta), then a local search from
        # the best grid points that beat the current solution (none: it stands)
        grid = _grid_starts(fs_Hz)
        costs = np.array([problem.evaluate(np.log(np.array(g)), jacobian=False)["cost"]
                          for g in grid])
        current = best[1]["cost"] if best is not None else math.inf
        tried = 0
        for idx in np.argsort(costs)[:3]:
            if costs[idx] >= current and best is not None and best[2]:
                break
            cand = run(grid[idx])
            tried += 1
            if best is None or (cand[2], -cand[1]["cost"]) > (best[2], -best[1]["cost"]):
                best = cand
        if tried:
            notes.append(f"searched from {tried} grid point(s) as well (start did not "
                         f"converge or fit below {s.retry_below_fit_pct:g} %)")
    if best is None:  # pragma: no cover - the grid search runs whenever there is no start
        raise IdentificationError("no starting point of the search could be evaluated")
    p, ev, converged, message, iterations = best
    ev = problem.jacobian(ev)       # the last accepted point's, for the covariance
    wn, zeta = math.exp(p[0]), math.exp(p[1])
    coef = ev["coef"]
    if wn > math.pi * fs_Hz:
        converged = False
        message = (f"wn = {wn:.3g} rad/s is above the Nyquist frequency of the fit rate "
                   f"({math.pi * fs_Hz:.3g} rad/s): the data do not determine it")

    # covariance of (ln wn, ln zeta, Kp, y0, y1, c0[, c1]) from the full Jacobian
    jac_rows = np.vstack([ev["jp"], ev["basis"]])
    n_par = len(jac_rows)
    sigma2 = _noise_variance(ev["resid"], fs_Hz, n_par, s.noise_level, band_Hz)
    _, r_full = orthonormalise(jac_rows)
    if np.any(np.diag(r_full) == 0):
        cov_full = np.full((n_par, n_par), np.nan)
        notes.append("singular Jacobian: standard errors unavailable")
    else:
        r_inv = np.linalg.inv(r_full)
        cov_full = sigma2 * (r_inv @ r_inv.T)
    # map to (Kp, wn, zeta)
    g = np.zeros((3, n_par))
    g[0, 2] = 1.0
    g[1, 0] = wn
    g[2, 1] = zeta
    cov = g @ cov_full @ g.T
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    n = len(y)
    trend = float(coef[4]) * 2.0 / ((n - 1) * dt) if s.estimate_trend else 0.0
    return SecondOrderFit(
        Kp=float(coef[0]), wn_rad_s=wn, zeta=zeta, Kp_se=float(se[0]), wn_se=float(se[1]),
        zeta_se=float(se[2]), fit_pct=fit_pct(ev), converged=bool(converged),
        message=message, iterations=int(iterations), t_s=t0_s + np.arange(n) * dt,
        y_N=y, y_fit_N=ev["y_fit"], fs_Hz=float(fs_Hz), offset_N=float(coef[3]),
        trend_N_per_s=trend, initial_output_N=(float(coef[1]), float(coef[2])),
        noise_sd_N=math.sqrt(sigma2), covariance=cov, start=start_est, notes=notes,
        _tests_of=(ev["resid"], u.copy(), s.resid_lags, s.resid_confidence))


def fisher_information(u: np.ndarray, Kp: float, wn_rad_s: float, zeta: float,
                       fs_Hz: float, noise_sd_N: float,
                       settings: IdentificationSettings | None = None) -> np.ndarray:
    """Fisher information of (Kp, wn_rad_s, zeta) for input ``u`` under white noise.

    The same model, nuisance parameters (initial state, offset, optional ramp) and
    sensitivities as :func:`fit_second_order`, evaluated at the true parameters on the
    noiseless response; the nuisance parameters are profiled out (Schur complement), so
    ``inv(result)`` is the Cramer-Rao bound of the estimator's covariance.

    Parameters
    ----------
    u : ndarray
        Input as the fit sees it (rE minus its window mean), sampled at ``fs_Hz``.
    Kp, wn_rad_s, zeta : float
        Parameters at which the information is evaluated (N per unit rE, rad/s, -).
    fs_Hz : float
        Sampling rate of ``u`` (the fit rate).
    noise_sd_N : float
        Standard deviation of white output noise at ``fs_Hz``.
    settings : IdentificationSettings, optional
        ``input_hold`` and ``estimate_trend`` as in the fit.

    Returns
    -------
    ndarray, shape (3, 3)
        Information matrix in units of the parameters (Kp, wn_rad_s, zeta).
    """
    s = settings or IdentificationSettings()
    u = np.asarray(u, dtype=float)
    v = smooth_hold_input(u) if s.input_hold is InputHold.SMOOTH else u
    dt = 1.0 / fs_Hz
    p = np.log(np.array([wn_rad_s, zeta], dtype=float))
    unit = _Problem(v, np.zeros(len(v)), dt, s.estimate_trend).evaluate(p, jacobian=False)
    y = Kp * unit["basis"][0]
    ev = _Problem(v, y, dt, s.estimate_trend).evaluate(p, jacobian=True)
    jac = np.vstack([ev["jp"], ev["basis"]])            # ln wn, ln zeta, Kp, nuisance...
    info_full = (jac @ jac.T) / noise_sd_N ** 2
    a, b, c = info_full[:3, :3], info_full[:3, 3:], info_full[3:, 3:]
    info = a - b @ np.linalg.solve(c, b.T)
    # reorder to (Kp, ln wn, ln zeta) and map logs to natural units
    order = [2, 0, 1]
    info = info[np.ix_(order, order)]
    scale = np.array([1.0, 1.0 / wn_rad_s, 1.0 / zeta])
    return info * np.outer(scale, scale)
