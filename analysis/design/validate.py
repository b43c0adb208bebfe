"""Validation by simulation: run protocols on virtual participants, identify, compare.

Each trial is simulated directly (``sim_backends.simulation.ParticipantSimulator`` fed with
the currents of ``protocols.waveforms.trial_waveform``, the reference calibration of the
participant), the session is identified by ``analysis.identify.identify_session`` exactly
as ``nmsid identify`` does, and the curves are compared with the participant's truth.

Physiological scatter: each trial's Kp, wn and zeta are the participant's curves times
``1 + sd z`` (one draw per trial and parameter). The design's prediction assumes z
independent standard normal (a plain ``{parameter: sd}`` dict here); a
:class:`ScatterModel` draws z otherwise (correlated between the parameters, heavy-tailed),
to validate the design under scatter it did not assume. ``scatter=None`` runs the plain
simulator (sensor noise only).

Draws are keyed by (participant seed, stream, sE, repeat); sensor noise is keyed the same
way. :func:`validate_protocols` runs the two protocols on different streams, so each gets
its own physiology and noise: the ratio of their errors is then a measurement with a
Monte-Carlo standard error (:func:`validated_ratio`), not 1 by construction as it is when
both see the same draws.

Metrics, per protocol, pooled over participants:

* ``curve_rms_rel``: RMS relative error of the right-family curve (least squares on the
  identified levels) at the paper's 15 levels, per parameter;
* ``level_rms_rel``: RMS relative error of the identified per-level values;
* ``selection_accuracy``: share of (participant, parameter) where AICc (the
  identification's own comparison, IQR rule included) picks the right family.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.curves import fit_curve
from nmsid.analysis.design.candidates import PAPER_LEVELS, Candidate
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.predict import SelectionAccuracy
from nmsid.analysis.design.prior import PARAMETERS, PerParameter
from nmsid.analysis.identify import identify_session
from nmsid.analysis.model_selection import compare_models
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.session_file import Session, Trial
from nmsid.protocols.waveforms import input_attrs, trial_waveform
from nmsid.sim_backends.curves import CurveModel, ParameterCurve
from nmsid.sim_backends.simulation import ParticipantSimulator


def _scaled(curve: ParameterCurve, factor: float) -> ParameterCurve:
    c = list(curve.coefficients)
    if curve.model is CurveModel.EXPONENTIAL:
        c[0] *= factor
    else:
        c = [v * factor for v in c]
    return ParameterCurve(curve.model, tuple(c))


@dataclass(frozen=True)
class ScatterModel:
    """How the per-trial relative scatter of (Kp, wn_rad_s, zeta) is drawn.

    Parameters
    ----------
    sd : dict
        Relative standard deviation per parameter (missing: 0).
    correlation : float
        Correlation between the three parameters' draws (same for every pair), in
        [0, 1).
    df : float, optional
        Student-t degrees of freedom (> 2; scaled to unit variance, so ``sd`` stays the
        standard deviation): heavier tails than the normal. None: normal.
    label : str
        How reports name it.

    Factors ``1 + sd z`` are kept at or above :attr:`MIN_FACTOR` (a heavy tail must not
    turn a gain negative).
    """

    sd: dict
    correlation: float = 0.0
    df: float | None = None
    label: str = "independent normal"

    MIN_FACTOR = 0.2

    def __post_init__(self):
        if not 0.0 <= self.correlation < 1.0:
            raise DesignError(f"scatter correlation = {self.correlation!r}: use a value in "
                              "[0, 1)")
        if self.df is not None and not self.df > 2:
            raise DesignError(f"scatter df = {self.df!r}: use degrees of freedom > 2 (finite "
                              "variance) or None for the normal")
        unknown = set(self.sd) - set(PARAMETERS)
        if unknown:
            raise DesignError(f"scatter names {sorted(unknown)}: use {list(PARAMETERS)}")

    def factors(self, rng: np.random.Generator) -> list[float]:
        """One trial's multiplicative factors for (Kp, wn_rad_s, zeta)."""
        c = self.correlation
        z = np.sqrt(1 - c) * rng.standard_normal(3) + np.sqrt(c) * rng.standard_normal()
        if self.df is not None:       # the same chi-square for all three: a jointly-t draw
            z = z * np.sqrt((self.df - 2) / rng.chisquare(self.df))
        return [max(self.MIN_FACTOR, 1 + self.sd.get(name, 0.0) * z[j])
                for j, name in enumerate(PARAMETERS)]


def alternative_scatter(sd: dict) -> ScatterModel:
    """A scatter model other than the design's own, with the same SDs: the three
    parameters move together (correlation 0.6: a trial with poorer electrode contact is
    weaker and slower) and the tails are heavy (Student-t, 3 degrees of freedom: now and
    then a trial far off)."""
    return ScatterModel(dict(sd), correlation=0.6, df=3.0,
                        label="correlated (0.6), heavy-tailed (t, 3 df)")


def _as_model(scatter) -> ScatterModel | None:
    if scatter is None or isinstance(scatter, ScatterModel):
        return scatter
    return ScatterModel(dict(scatter)) if any(scatter.values()) else None


def simulate_session(vp, candidate: Candidate, *, scatter: dict | ScatterModel | None = None,
                     seed: int = 0, stream: int = 0) -> Session:
    """One session of ``candidate`` on virtual participant ``vp`` (in memory).

    ``vp`` is a template participant (``sim_backends.participant``) or a musculoskeletal
    one (``sim_backends.msk_participant``: its own MuJoCo simulator and the calibration its
    ramp finds). ``scatter`` (relative SDs per trial of Kp, wn_rad_s, zeta, drawn
    independent normal; or a :class:`ScatterModel`) scales the template's curves; on a
    musculoskeletal participant it scales the physics behind them
    (:meth:`~nmsid.sim_backends.msk_participant.MskParticipant.trial_variant`: electrode reach,
    muscle and mount speed, mount damping) by the same factors. ``stream``: two calls
    with the same seed and stream draw the same physiology and noise for a shared
    (sE, repeat); different streams draw independently."""
    model = _as_model(scatter)
    cfg = candidate.config()
    p = cfg.protocol
    musculoskeletal = hasattr(vp, "make_simulator")  # MuJoCo participant: its own simulator
    cal = vp.ramp_calibration() if musculoskeletal else \
        vp.calibration.as_session_calibration()
    trials: list = []
    attrs = input_attrs(p)
    for s in p.sE_levels:
        wf = trial_waveform(p, s, cal)
        for r in range(1, p.repeats + 1):
            key = [int(seed) & 0xFFFFFFFF, int(round(s * 1000)), r, 9173]
            if stream:
                key.append(int(stream))
            rng = np.random.default_rng(key)
            who = vp
            if model is not None:
                f = model.factors(rng)
                if musculoskeletal:   # the same relative SDs on the physics behind them
                    who = vp.trial_variant(gain=f[0], speed=f[1], damping=f[2])
                else:
                    who = dataclasses.replace(vp, Kp=_scaled(vp.Kp, f[0]),
                                              wn_rad_s=_scaled(vp.wn_rad_s, f[1]),
                                              zeta=_scaled(vp.zeta, f[2]))
            who = dataclasses.replace(who, seed=int(rng.integers(0, 2 ** 31 - 1)))
            sim = who.make_simulator(p.fs_Hz) if musculoskeletal else \
                ParticipantSimulator(who, p.fs_Hz)
            force = sim.simulate(wf.I_ext_mA, wf.I_flex_mA).force_N
            trials.append(Trial(sE=float(s), repeat=r, fs_Hz=p.fs_Hz, rE=wf.rE,
                                I_ext_mA=wf.I_ext_mA, I_flex_mA=wf.I_flex_mA,
                                force_N=np.asarray(force, dtype=float), steady_s=p.steady_s,
                                chirp_s=p.chirp_s, chirp_f0_Hz=p.chirp_f0_Hz,
                                chirp_f1_Hz=p.chirp_f1_Hz, carrier_Hz=p.carrier_Hz,
                                name=f"t{len(trials) + 1:03d}", extra_attrs=dict(attrs)))
    return Session(path=f"<simulated {vp.code}>", participant=vp.code, created_utc="",
                   software="nmsid design validation", calibration=cal, trials=trials,
                   config_json=cfg.to_json())


@dataclass
class ProtocolOutcome:
    """Realised errors of one protocol over the simulated participants."""

    label: str
    stimulation_s: float
    curve_err: np.ndarray
    """[participant, paper level, parameter] relative error of the right-family curve."""
    level_err: list = field(default_factory=list)
    """Per participant: [level, parameter] relative error of the identified values."""
    selected_right: np.ndarray | None = None
    """[participant, parameter] True where AICc picked the right family."""

    def curve_rms_rel(self) -> PerParameter:
        """RMS relative error of the right-family curve, pooled over participants and the
        paper's 15 levels."""
        return PerParameter(**{n: float(np.sqrt(np.nanmean(self.curve_err[:, :, j] ** 2)))
                               for j, n in enumerate(PARAMETERS)})

    def level_rms_rel(self) -> PerParameter:
        """RMS relative error of the identified per-level values."""
        e = np.concatenate(self.level_err, axis=0)
        return PerParameter(**{n: float(np.sqrt(np.nanmean(e[:, j] ** 2)))
                               for j, n in enumerate(PARAMETERS)})

    def selection_accuracy(self) -> SelectionAccuracy:
        """Share of (participant, parameter) where AICc picked the right family."""
        right = self.selected_right
        if right is None:
            raise ValueError("no selection was recorded for this outcome")
        return SelectionAccuracy(
            per_parameter={n: float(right[:, j].mean()) for j, n in enumerate(PARAMETERS)},
            overall=float(right.mean()))


#: How the validation identifies its simulated sessions: the level fits only. Trial quality
#: control (which looks for artefacts the simulation does not make) and the per-repeat
#: scatter fits (which the score does not use) cost nine tenths of the time of
#: ``identify_session`` (6.6 -> 0.64 CPU s a paper session, issue 39) and are skipped: each
#: protocol is scored on the plain average of its repeats, the paper's own method.
VALIDATION_SETTINGS = IdentificationSettings(qc=False)


def run_protocol(participants, candidate: Candidate, *,
                 scatter: dict | ScatterModel | None = None, seed: int = 0, stream: int = 0,
                 settings: IdentificationSettings | None = None,
                 on_session=None) -> ProtocolOutcome:
    """Simulate, identify and score ``candidate`` on every participant (``scatter``,
    ``stream``: see :func:`simulate_session`). ``settings`` default
    :data:`VALIDATION_SETTINGS`; ``on_session()`` is called after each participant."""
    s = settings or VALIDATION_SETTINGS
    grid = np.asarray(PAPER_LEVELS, dtype=float)
    curve_err = np.full((len(participants), len(grid), 3), np.nan)
    right = np.zeros((len(participants), 3), dtype=bool)
    level_err = []
    for i, vp in enumerate(participants):
        session = simulate_session(vp, candidate, scatter=scatter, seed=seed * 100003 + i,
                                   stream=stream)
        result = identify_session(session, s, trial_scatter=False)
        levels = np.array([lv.sE for lv in result.levels])
        est = np.array([[lv.fit.Kp, lv.fit.wn_rad_s, lv.fit.zeta] if lv.fit is not None
                        else [np.nan] * 3 for lv in result.levels])
        truth_lv = np.array([vp.true_parameters(x) for x in levels])
        level_err.append(est / truth_lv - 1.0)
        for j, name in enumerate(PARAMETERS):
            true_curve = getattr(vp, name)
            ok = np.isfinite(est[:, j])
            fit = fit_curve(true_curve.model.value, levels[ok], est[ok, j])
            truth = true_curve(grid)
            if fit.coefficients is not None:
                curve_err[i, :, j] = np.asarray(fit.predict(grid)) / truth - 1.0
            cmp = compare_models(levels[ok], est[ok, j], name, vp.code, s)
            right[i, j] = cmp.selected == true_curve.model.value
        if on_session is not None:
            on_session()
    return ProtocolOutcome(candidate.label or candidate.describe(), candidate.stimulation_s,
                           curve_err, level_err, right)


def _per_participant_ms(outcome: ProtocolOutcome) -> np.ndarray:
    """[participant, parameter] mean squared relative curve error over the 15 levels."""
    with np.errstate(invalid="ignore"):
        return np.nanmean(outcome.curve_err ** 2, axis=1)


@dataclass(frozen=True)
class ValidatedRatio:
    """Realised RMS curve errors, proposal / paper (:func:`validated_ratio`).

    Attributes
    ----------
    max : float
        The largest ratio over the parameters.
    per_parameter : dict of str to float
        The ratio per parameter (``Kp``, ``wn_rad_s``, ``zeta``).
    se_per_parameter : dict of str to float
        Its Monte-Carlo standard error (NaN with one participant).
    max_se : float
        The standard error of the parameter giving ``max``.
    """

    max: float
    per_parameter: dict[str, float]
    se_per_parameter: dict[str, float]
    max_se: float


def validated_ratio(proposal: ProtocolOutcome, paper: ProtocolOutcome) -> ValidatedRatio:
    """Ratios of the realised RMS curve errors, proposal / paper, per parameter; ``max``;
    and their Monte-Carlo standard errors.

    Pooled over participants and the paper's 15 levels before the ratio (a per-level ratio
    of RMS values from a few participants scatters too much to take its maximum).

    Returns
    -------
    ValidatedRatio
        The standard errors come from the spread of the participants' mean squared errors
        (delta method on ``sqrt(A / B)``, the two protocols' draws independent, as
        :func:`validate_protocols` runs them).
    """
    a, b = proposal.curve_rms_rel().to_dict(), paper.curve_rms_rel().to_dict()
    per = {n: a[n] / b[n] for n in PARAMETERS}
    ms_a, ms_b = _per_participant_ms(proposal), _per_participant_ms(paper)
    se = {}
    for j, n in enumerate(PARAMETERS):
        rel_var = 0.0
        for ms in (ms_a[:, j], ms_b[:, j]):
            ms = ms[np.isfinite(ms)]
            rel_var += (np.var(ms, ddof=1) / (len(ms) * np.mean(ms) ** 2)
                        if len(ms) > 1 and np.mean(ms) > 0 else np.nan)
        se[n] = float(per[n] * 0.5 * np.sqrt(rel_var))
    worst = max(per, key=lambda n: per[n])
    return ValidatedRatio(max=per[worst], per_parameter=per, se_per_parameter=se,
                          max_se=se[worst])
