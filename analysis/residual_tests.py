"""Residual analysis as MATLAB's ``resid``: whiteness and independence from the input.

Two tests on the output error e = y - yhat of a fitted model:

* autocorrelation of e at lags 1..M within +- z / sqrt(N) (white-noise null);
* cross-correlation of e with the input u at lags -M..M within
  +- z sqrt(sum_k rho_e(k) rho_u(k)) / sqrt(N) (Bartlett's variance of a cross-correlation
  of two independent series; it reduces to z / sqrt(N) when either is white).

z is the two-sided normal quantile of the confidence (2.576 for 99 %): the bounds MATLAB
draws. With 25 lags each at 99 %, a white residual would cross some bound one time in
five, so the pass/fail verdicts use the family-wise (Bonferroni) level instead:
z_fw = quantile(1 - (1 - confidence) / (2 M)), and a white, input-independent residual
passes with the stated confidence. The cross-correlation
test is the informative one for an output-error model (is anything in u left unexplained?);
the whiteness test fails by construction on low-passed data sampled well above twice the
cut-off, because the filter itself correlates neighbouring samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from nmsid.protocols.reprs import html_repr, short_repr

#: standard normal quantile (as scipy.special.ndtri; the stdlib's spares scipy.special's
#: 0.3 s import on every ``nmsid identify``)
ndtri = NormalDist().inv_cdf


@dataclass
class ResidualTests:
    """Outcome of the residual tests (correlations are normalised to [-1, 1])."""

    lags: np.ndarray
    """Lags 0..M of the autocorrelation (samples)."""
    autocorrelation: np.ndarray
    """rho_e(lag), lags 0..M."""
    autocorrelation_bound: float
    """Per-lag bound (as MATLAB's ``resid`` draws it)."""
    cross_lags: np.ndarray
    """Lags -M..M of the cross-correlation (positive: input leads residual)."""
    cross_correlation: np.ndarray
    cross_correlation_bound: float
    confidence: float
    whiteness_pass: bool
    """No autocorrelation at lags 1..M outside the family-wise bound."""
    independence_pass: bool
    """No cross-correlation at lags -M..M outside the family-wise bound."""
    autocorrelation_verdict_bound: float = float("nan")
    """Family-wise bound used for ``whiteness_pass``."""
    cross_correlation_verdict_bound: float = float("nan")
    """Family-wise bound used for ``independence_pass``."""

    def __repr__(self) -> str:
        return short_repr("ResidualTests", self.summary())

    _repr_html_ = html_repr

    def summary(self) -> str:
        """One line: both verdicts and the worst excursion of each."""
        worst_a = float(np.max(np.abs(self.autocorrelation[1:]))) if len(self.lags) > 1 else 0.0
        worst_c = float(np.max(np.abs(self.cross_correlation)))
        return (f"whiteness {'pass' if self.whiteness_pass else 'fail'} (max |r_e| "
                f"{worst_a:.3f}, per-lag bound {self.autocorrelation_bound:.3f}); input "
                f"independence {'pass' if self.independence_pass else 'fail'} (max |r_eu| "
                f"{worst_c:.3f}, per-lag bound {self.cross_correlation_bound:.3f}); verdicts "
                f"at the family-wise {self.confidence:.0%} level")


def _normalised_xcorr(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """r_ab(k) = sum_t a(t+k) b(t) / sqrt(sum a^2 sum b^2), k = -max_lag..max_lag."""
    n = len(a)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    fa = np.fft.rfft(a, nfft)
    fb = np.fft.rfft(b, nfft)
    full = np.fft.irfft(fa * np.conj(fb), nfft)
    lags = np.arange(-max_lag, max_lag + 1)
    r = full[lags % nfft]
    scale = np.sqrt(np.dot(a, a) * np.dot(b, b))
    return r / scale if scale > 0 else np.zeros_like(r)


def residual_tests(residual: np.ndarray, u: np.ndarray, max_lag: int = 25,
                   confidence: float = 0.99) -> ResidualTests:
    """Run both residual tests.

    Parameters
    ----------
    residual : ndarray
        Output error y - yhat (any units).
    u : ndarray
        Input of the same length.
    max_lag : int
        Largest lag M in samples (MATLAB default 25).
    confidence : float
        Confidence level of the bounds (MATLAB default 0.99).

    Returns
    -------
    ResidualTests

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> r = residual_tests(rng.standard_normal(4000), rng.standard_normal(4000))
    >>> r.whiteness_pass, r.independence_pass
    (True, True)
    """
    e = np.asarray(residual, dtype=float) - np.mean(residual)
    x = np.asarray(u, dtype=float) - np.mean(u)
    n = len(e)
    max_lag = int(min(max_lag, max(n - 1, 1)))
    z = float(ndtri(0.5 + confidence / 2))
    z_auto = float(ndtri(1 - (1 - confidence) / (2 * max_lag)))
    z_cross = float(ndtri(1 - (1 - confidence) / (2 * (2 * max_lag + 1))))
    r_eu = _normalised_xcorr(e, x, max_lag)
    # Bartlett's sum over a wider lag range than tested: rE is strongly autocorrelated
    bartlett_lag = int(min(4 * max_lag, max(n - 1, 1)))
    r_ee = _normalised_xcorr(e, e, bartlett_lag)
    r_uu = _normalised_xcorr(x, x, bartlett_lag)
    auto = r_ee[bartlett_lag:bartlett_lag + max_lag + 1]
    auto_bound = z / np.sqrt(n)
    bartlett = float(np.sum(r_ee * r_uu))
    cross_bound = z * np.sqrt(max(bartlett, 1.0 / n) / n)
    return ResidualTests(
        lags=np.arange(max_lag + 1), autocorrelation=auto, autocorrelation_bound=auto_bound,
        cross_lags=np.arange(-max_lag, max_lag + 1), cross_correlation=r_eu,
        cross_correlation_bound=cross_bound, confidence=confidence,
        whiteness_pass=bool(np.all(np.abs(auto[1:]) <= auto_bound * z_auto / z)),
        independence_pass=bool(np.all(np.abs(r_eu) <= cross_bound * z_cross / z)),
        autocorrelation_verdict_bound=auto_bound * z_auto / z,
        cross_correlation_verdict_bound=cross_bound * z_cross / z)
