"""Predicted precision of a protocol for a prior twin: Cramer-Rao bounds at three stages.

1. **Per level**: the Fisher information of (Kp, wn, zeta) for one trial's excitation at
   each sE (:func:`nmsid.analysis.second_order.fisher_information`: the fit's own model,
   sensitivities and nuisance parameters, at the prior's parameters), times the repeats
   (the identification averages them), inverted. Noise: the prior's white sensor noise
   (RMS ``noise_N`` at the raw rate) seen at the fit rate after the 25 Hz low-pass, i.e.
   variance ``noise_N^2 fit_fs / raw_fs`` per fit sample (same spectral density).
   Plus a per-trial physiological scatter (``scatter``: relative SD of each parameter
   from trial to trial, independent between trials), which the sensor-noise bound does not
   see and which only more trials average away. Without it a design trades seconds for
   precision one to one; the paper's own tables show scatter of several per cent about
   the curves (see :data:`DEFAULT_SCATTER`).
2. **Curves over sE**: the right family (the prior's) fitted by weighted least squares to
   the per-level estimates, Gauss-Markov covariance ``inv(G' W G)`` of its coefficients;
   from it the standard error of the curve at the paper's 15 levels (how protocols with
   different level sets are compared), and of the quantities the study reads off the
   curves: the extremum (sE and value) of a quadratic, the rate of an exponential, the
   slope of a line.
3. **Model choice**: the probability that AICc picks the right family, by Monte-Carlo:
   per-level values drawn from the predicted per-level covariance around the prior's
   curve, then ``analysis.model_selection.compare_models`` exactly as ``nmsid identify``
   runs it (IQR outlier rule on wn and zeta included).

What it leaves out is said in every report: physiological scatter between trials and
levels (fatigue, potentiation, electrode shifts), model error (dead time, nonlinear
recruitment), and curves outside the three families.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from nmsid.analysis.design.candidates import PAPER_LEVELS, Candidate
from nmsid.analysis.design.prior import PARAMETERS, PerParameter, Prior, PriorParticipant
from nmsid.analysis.model_selection import compare_models
from nmsid.analysis.second_order import fisher_information
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.waveforms import rE_signal

#: Relative per-trial scatter of (Kp, wn, zeta) assumed by default. Order of magnitude
#: from the paper's AICc tables: with n = 15 levels of 3 averaged trials, Tables 1, 4 and 7
#: imply residual SDs about the individual curves of roughly 5-30 % of Kp and a few per
#: cent of wn and zeta; we take 10 %, 5 %, 5 % per trial (a level of 3 trials: / sqrt 3).
DEFAULT_SCATTER = {"Kp": 0.10, "wn_rad_s": 0.05, "zeta": 0.05}

REFERENCE_AMPLITUDE = 0.5
"""Fisher information is computed at this rE amplitude and scaled by (A / 0.5)^2 (exact:
the model is linear in the input)."""


@dataclass
class Prediction:
    """Predicted standard errors of one protocol for every prior participant.

    Arrays are indexed [participant, level, parameter] with parameters (Kp, wn_rad_s,
    zeta); ``curve_se`` is at the paper's 15 levels (``PAPER_LEVELS``).
    """

    candidate: Candidate
    codes: list[str]
    level_se: np.ndarray
    curve_se: np.ndarray
    curve_value: np.ndarray
    derived: list[dict[str, DerivedQuantities]] = field(default_factory=list)
    """Per participant: {parameter: its curve's :class:`DerivedQuantities`}."""
    selection: SelectionAccuracy | None = None
    """Monte-Carlo probability of selecting the right family (``overall``, per parameter)."""


def curve_gradient(model: str, coefficients, sE) -> np.ndarray:
    """d curve / d coefficients at ``sE`` (rows: levels)."""
    x = np.atleast_1d(np.asarray(sE, dtype=float))
    c = coefficients
    if model == "linear":
        return np.column_stack([np.ones_like(x), x])
    if model == "quadratic":
        return np.column_stack([np.ones_like(x), x, x * x])
    if model == "exponential":
        e = np.exp(c[1] * x)
        return np.column_stack([e, c[0] * x * e])
    raise ValueError(f"curve model {model!r}: valid are linear, quadratic, exponential")


@dataclass(frozen=True)
class DerivedQuantities:
    """The quantities a study reads off one curve, each ``(estimate, standard error)``.

    Attributes
    ----------
    model : str
        The curve's family (``linear``, ``quadratic``, ``exponential``).
    extremum_sE, extremum_value : tuple of float or None
        Quadratic: the vertex -b / 2c and the value there, a - b^2 / 4c (None otherwise).
    rate : tuple of float or None
        Exponential: b, per unit sE (None otherwise).
    slope : tuple of float or None
        Linear: b (None otherwise).
    """

    model: str
    extremum_sE: tuple[float, float] | None = None
    extremum_value: tuple[float, float] | None = None
    rate: tuple[float, float] | None = None
    slope: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, tuple[float, float]]:
        """``{quantity: (estimate, se)}`` of the quantities this family has (JSON-ready)."""
        out = {}
        for name in ("extremum_sE", "extremum_value", "rate", "slope"):
            value = getattr(self, name)
            if value is not None:
                out[name] = value
        return out


def derived_quantities(model: str, coefficients, cov: np.ndarray) -> DerivedQuantities:
    """The quantities a study reads off a curve, with delta-method standard errors.

    quadratic: ``extremum_sE`` = -b / 2c and ``extremum_value`` = a - b^2 / 4c;
    exponential: ``rate`` b (per unit sE); linear: ``slope`` b.

    Returns
    -------
    DerivedQuantities
    """
    c = np.asarray(coefficients, dtype=float)
    if model == "quadratic":
        a, b, q = c
        g_x = np.array([0.0, -1 / (2 * q), b / (2 * q * q)])
        g_v = np.array([1.0, -b / (2 * q), b * b / (4 * q * q)])
        return DerivedQuantities(
            model, extremum_sE=(float(-b / (2 * q)), float(np.sqrt(g_x @ cov @ g_x))),
            extremum_value=(float(a - b * b / (4 * q)), float(np.sqrt(g_v @ cov @ g_v))))
    if model == "exponential":
        return DerivedQuantities(model, rate=(float(c[1]), float(np.sqrt(cov[1, 1]))))
    return DerivedQuantities(model, slope=(float(c[1]), float(np.sqrt(cov[1, 1]))))


@dataclass(frozen=True)
class SelectionAccuracy:
    """Share of choices where AICc selects the right (the prior's) family: predicted by
    Monte-Carlo (:meth:`Predictor.selection_accuracy`) or realised in a validation
    (:meth:`~nmsid.analysis.design.validate.ProtocolOutcome.selection_accuracy`).

    Attributes
    ----------
    per_parameter : dict of str to float
        Per parameter (Kp, wn_rad_s, zeta).
    overall : float
        Over all parameters.
    draws_per_participant : int or None
        Monte-Carlo draws per prior participant (None: realised, not drawn).
    """

    per_parameter: dict[str, float]
    overall: float
    draws_per_participant: int | None = None

    def to_dict(self) -> dict[str, float]:
        """``{parameter: p, ..., "overall": p[, "draws_per_participant": n]}`` (JSON-ready,
        the layout of ``design.json``)."""
        out = {**self.per_parameter, "overall": self.overall}
        if self.draws_per_participant is not None:
            out["draws_per_participant"] = self.draws_per_participant
        return out





class Predictor:
    """Computes :class:`Prediction` objects for one prior, caching per-input information.

    Parameters
    ----------
    prior : Prior
    settings : IdentificationSettings, optional
        Fit rate, input hold and trend as the identification will use them.
    raw_fs_Hz : float
        Sampling rate of the force (the protocol's fs_Hz).
    """

    def __init__(self, prior: Prior, settings: IdentificationSettings | None = None,
                 raw_fs_Hz: float = 2000.0, scatter: dict | None = None):
        self.prior = prior
        self.scatter = dict(DEFAULT_SCATTER if scatter is None else scatter)
        for name in PARAMETERS:
            v = self.scatter.setdefault(name, 0.0)
            if not (isinstance(v, (int, float)) and 0 <= v < 1):
                raise ValueError(f"scatter of {name} = {v!r}: give a relative SD in [0, 1)")
        self.settings = settings or IdentificationSettings()
        self.raw_fs_Hz = float(raw_fs_Hz)
        self.fit_fs_Hz = float(self.settings.fit_fs_Hz or raw_fs_Hz)
        self._info: dict = {}

    # -- stage 1 --------------------------------------------------------------------
    def _input_key(self, c: Candidate) -> tuple:
        return (c.input_kind, c.chirp_s, c.chirp_f0_Hz, c.chirp_f1_Hz,
                c.multisine_tones if c.input_kind == "multisine" else 0)

    def fit_input(self, c: Candidate) -> np.ndarray:
        """The excitation as the fit sees it (window after the lead-in, fit rate, mean
        removed) at the reference amplitude."""
        p = replace(c, rE_amplitude=REFERENCE_AMPLITUDE).config().protocol
        rE = rE_signal(p)
        q = max(1, int(np.floor(p.fs_Hz / self.fit_fs_Hz + 1e-9)))
        u = rE[int(round(p.steady_s * p.fs_Hz)):][::q]
        return u - u.mean()

    def level_information(self, c: Candidate, who: PriorParticipant, sE: float
                          ) -> np.ndarray:
        """Information of ONE trial at the reference amplitude (cached)."""
        key = (self._input_key(c), who.code, round(float(sE), 9))
        if key not in self._info:
            ukey = ("u",) + self._input_key(c)
            if ukey not in self._info:
                self._info[ukey] = self.fit_input(c)
            u = self._info[ukey]
            kp, wn, z = who.parameters_at(sE)
            sd_fit = who.noise_N * np.sqrt(self.fit_fs_Hz / self.raw_fs_Hz)
            fs = self.raw_fs_Hz / max(1, int(np.floor(self.raw_fs_Hz / self.fit_fs_Hz + 1e-9)))
            self._info[key] = fisher_information(u, kp, wn, z, fs, sd_fit, self.settings)
        return self._info[key]

    def level_covariance(self, c: Candidate, who: PriorParticipant, sE: float,
                         with_scatter: bool = True) -> np.ndarray:
        """Covariance of the level's estimate (repeats averaged): sensor-noise bound plus
        the physiological scatter."""
        scale = (c.rE_amplitude / REFERENCE_AMPLITUDE) ** 2
        per_trial = np.linalg.inv(self.level_information(c, who, sE) * scale)
        if with_scatter:
            values = np.array(who.parameters_at(sE))
            rel = np.array([self.scatter[name] for name in PARAMETERS])
            per_trial = per_trial + np.diag((rel * values) ** 2)
        return per_trial / c.repeats

    # -- stage 2 --------------------------------------------------------------------
    def predict(self, c: Candidate, *, derived: bool = True, with_scatter: bool = True
                ) -> Prediction:
        """Per-level and curve standard errors of ``c`` for every prior participant."""
        levels = np.asarray(c.sE_levels, dtype=float)
        grid = np.asarray(PAPER_LEVELS, dtype=float)
        people = self.prior.participants
        level_se = np.empty((len(people), len(levels), 3))
        curve_se = np.empty((len(people), len(grid), 3))
        curve_val = np.empty((len(people), len(grid), 3))
        der = []
        for i, who in enumerate(people):
            var = np.array([np.diag(self.level_covariance(c, who, s, with_scatter))
                            for s in levels])
            level_se[i] = np.sqrt(var)
            d_who = {}
            for j, name in enumerate(PARAMETERS):
                curve = who.curves[name]
                G = curve_gradient(curve.model, curve.coefficients, levels)
                cov = np.linalg.pinv(G.T @ (G / var[:, j:j + 1]))
                g = curve_gradient(curve.model, curve.coefficients, grid)
                curve_se[i, :, j] = np.sqrt(np.einsum("ij,jk,ik->i", g, cov, g))
                curve_val[i, :, j] = curve(grid)
                if derived:
                    d_who[name] = derived_quantities(curve.model, curve.coefficients, cov)
            der.append(d_who)
        return Prediction(c, [p.code for p in people], level_se, curve_se, curve_val, der)

    # -- stage 3 --------------------------------------------------------------------
    def selection_accuracy(self, pred: Prediction, draws: int = 100,
                           seed: int = 0) -> SelectionAccuracy:
        """Probability that AICc selects the prior's family, per parameter and overall.

        Each draw perturbs the per-level values of one participant by independent normal
        errors with the predicted per-level standard errors and runs the identification's
        model comparison on them.
        """
        rng = np.random.default_rng(seed)
        levels = np.asarray(pred.candidate.sE_levels, dtype=float)
        hits = np.zeros(3)
        total = 0
        for i, who in enumerate(self.prior.participants):
            for j, name in enumerate(PARAMETERS):
                truth = who.curves[name](levels)
                model = who.curves[name].model
                z = rng.standard_normal((draws, len(levels)))
                for d in range(draws):
                    cmp = compare_models(levels, truth + pred.level_se[i, :, j] * z[d], name,
                                         who.code, self.settings)
                    hits[j] += cmp.selected == model
            total += draws
        return SelectionAccuracy(
            per_parameter={name: float(hits[j] / total) for j, name in enumerate(PARAMETERS)},
            overall=float(hits.sum() / (3 * total)), draws_per_participant=int(draws))


@dataclass(frozen=True)
class SdRatio:
    """Predicted curve standard errors, proposal / paper (:func:`sd_ratio`).

    Attributes
    ----------
    max : float
        The largest ratio over participants, parameters and levels (the designer's
        constraint).
    per_parameter : dict of str to float
        The largest ratio per parameter.
    median_participant_max : float
        The largest over parameters and levels of the median over participants.
    """

    max: float
    per_parameter: dict[str, float]
    median_participant_max: float


def sd_ratio(proposal: Prediction, paper: Prediction) -> SdRatio:
    """Ratios of the proposal's predicted curve standard errors to the paper protocol's.

    Compared on the paper's 15 levels through the curves (protocols with different level
    sets estimate different points; both estimate the same curve), per participant,
    parameter and level.

    Returns
    -------
    SdRatio
    """
    r = proposal.curve_se / paper.curve_se
    per_param = {name: float(r[:, :, j].max()) for j, name in enumerate(PARAMETERS)}
    return SdRatio(max=float(r.max()), per_parameter=per_param,
                   median_participant_max=float(np.median(r, axis=0).max()))


def derived_ratio(proposal: Prediction, paper: Prediction) -> float:
    """Largest ratio of the derived quantities' standard errors (extremum, rate, slope)."""
    worst = 0.0
    for a, b in zip(proposal.derived, paper.derived, strict=True):
        for name in a:
            ref_of = b[name].to_dict()
            for q, (_, se) in a[name].to_dict().items():
                ref = ref_of[q][1]
                if ref > 0 and np.isfinite(se):
                    worst = max(worst, se / ref)
    return float(worst)


def relative_curve_se(pred: Prediction) -> PerParameter:
    """Largest relative curve standard error (SE / |value|) per parameter."""
    rel = pred.curve_se / np.abs(pred.curve_value)
    return PerParameter(**{name: float(rel[:, :, j].max())
                           for j, name in enumerate(PARAMETERS)})
