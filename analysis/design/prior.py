"""The prior twin a design is computed for: curves of Kp, wn, zeta over sE and the noise.

Two sources: a participant's own ``twin.json`` (from ``nmsid identify`` on a first short
session) or the simulator's seeded population (``sim_backends.population``), which differs
the way the paper's ten participants do. The curve families in the prior are taken as the
"right" families when the design predicts the probability of selecting them.

Examples
--------
>>> prior = population_prior(3, seed=1)
>>> [p.code for p in prior.participants]
['S01', 'S02', 'S03']
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np

from nmsid.analysis.curves import evaluate_curve
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.twin import Twin
from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS
from nmsid.sim_backends.joint_participants import joint_sensor
from nmsid.sim_backends.population import make_population

PARAMETERS = ("Kp", "wn_rad_s", "zeta")

#: Sensor noise assumed for a twin file (which does not store it): the middle of the
#: 0.02-0.06 N RMS the paper's rig and the simulator's population have.
DEFAULT_NOISE_N = 0.04


def default_noise(joint: str = DEFAULT_JOINT) -> float:
    """Sensor noise RMS assumed for a twin of ``joint``, in its unit: the elbow's
    :data:`DEFAULT_NOISE_N` scaled as the joint's simulated sensor chain is (its Fmax over
    the elbow's: 0.4 N m at the knee, 0.16 N m at the ankle); a joint nmsid does not know
    (a twin from another lab's registry): the elbow's."""
    if joint not in JOINTS:
        return DEFAULT_NOISE_N
    return DEFAULT_NOISE_N * joint_sensor(joint).noise_N / joint_sensor(DEFAULT_JOINT).noise_N


@dataclass(frozen=True)
class PriorCurve:
    """One parameter's curve over sE: ``model`` in linear / quadratic / exponential."""

    model: str
    coefficients: tuple[float, ...]

    def __call__(self, sE) -> np.ndarray:
        return evaluate_curve(self.model, self.coefficients, sE)


@dataclass(frozen=True)
class PriorParticipant:
    """What the design assumes about one participant.

    ``noise_N`` is the RMS of white force noise at ``raw_fs_Hz`` (the sensor's), per trial.
    """

    code: str
    curves: dict
    noise_N: float
    sE_range: tuple[float, float] = (0.30, 1.00)

    def parameters_at(self, sE: float) -> tuple[float, float, float]:
        kp, wn, zeta = (float(self.curves[name](sE)) for name in PARAMETERS)
        return kp, wn, zeta


@dataclass(frozen=True)
class Prior:
    """A set of prior participants (one for a twin, many for a population)."""

    participants: tuple
    source: str
    joint: str = DEFAULT_JOINT
    """The joint the prior is of (a twin's, or the population's): its unit is the one of
    Kp and ``noise_N``; the validation simulates participants of that joint."""


def _check(code: str, curves: dict, where: str) -> None:
    grid = np.linspace(0.30, 1.00, 15)
    for name in PARAMETERS:
        c = curves[name]
        if c.model not in ("linear", "quadratic", "exponential"):
            raise DesignError(f"{where}: {name} curve model {c.model!r} cannot be designed "
                              "for; valid: linear, quadratic, exponential")
        vals = c(grid)
        if not np.all(np.isfinite(vals)) or (name != "Kp" and np.any(vals <= 0)):
            raise DesignError(f"{where}: {name} of {code} is not finite and positive over "
                              "sE 0.30-1.00; the twin cannot be a prior")


def twin_prior(path, noise_N: float | None = None) -> Prior:
    """A prior from one participant's ``twin.json``; ``noise_N`` in the twin's unit
    (default :func:`default_noise` of its joint).

    Raises
    ------
    analysis.errors.TwinFileError
        If the file is missing or breaks the twin format.
    DesignError
        If a curve cannot be a prior (constant, or wn/zeta not positive), or noise_N <= 0.
    """
    if noise_N is not None and not (noise_N > 0 and math.isfinite(noise_N)):
        raise DesignError(f"--noise-N {noise_N!r}: give the sensor's RMS noise in N (> 0)")
    twin = Twin.load(path)
    if noise_N is None:
        noise_N = default_noise(twin.joint)
    if twin.muscle_model is not None:
        raise DesignError(f"{path}: this twin has the muscle form (muscle_model "
                          f"{twin.muscle_model.get('form')!r}); nmsid design plans for the "
                          "second-order form only: give a twin without 'muscle_model' (as "
                          "nmsid identify writes it)")
    curves = {name: PriorCurve(twin.parameters[name].model,
                               tuple(float(v) for v in twin.parameters[name].coefficients))
              for name in PARAMETERS}
    _check(twin.participant, curves, str(path))
    lo, hi = twin.sE_range
    return Prior((PriorParticipant(twin.participant, curves, float(noise_N),
                                   (float(lo), float(hi))),), source=str(path),
                 joint=twin.joint)


def population_prior(n: int = 20, seed: int = 0, joint: str = DEFAULT_JOINT) -> Prior:
    """A prior from the simulator's population of ``joint``: ``n`` participants from
    ``seed``."""
    out = []
    for vp in make_population(n, seed, joint=joint):
        curves = {name: PriorCurve(getattr(vp, name).model.value,
                                   tuple(getattr(vp, name).coefficients))
                  for name in PARAMETERS}
        lo, hi = vp.sE_range
        out.append(PriorParticipant(vp.code, curves, float(vp.sensor.noise_N),
                                    (float(lo), float(hi))))
    return Prior(tuple(out), joint=joint, source=f"simulator population (n={n}, seed={seed}"
                 + ("" if joint == DEFAULT_JOINT else f", {joint}") + ")")


_SE_COLUMNS = {"Kp": "Kp_se", "wn_rad_s": "wn_se", "zeta": "zeta_se"}


@dataclass(frozen=True)
class PerParameter:
    """One number per second-order parameter (a relative SD, a relative error, ...).

    Attributes
    ----------
    Kp, wn_rad_s, zeta : float
    """

    Kp: float
    wn_rad_s: float
    zeta: float

    def to_dict(self) -> dict[str, float]:
        """``{"Kp": ..., "wn_rad_s": ..., "zeta": ...}`` (JSON-ready; the ``scatter`` that
        :class:`~nmsid.analysis.design.predict.Predictor` and ``run_design`` take)."""
        return {name: getattr(self, name) for name in PARAMETERS}


def scatter_from_parameters(path, prior: Prior) -> PerParameter:
    """Per-trial relative scatter measured on a first session (``parameters.csv``).

    For each parameter: the identified values' relative residuals about the prior's curve
    (the twin fitted to the same session), mean square corrected for the k fitted
    coefficients, minus the part the fit's own standard errors explain (sensor noise),
    times the trials averaged per level.

    Returns
    -------
    PerParameter
        Relative SDs per trial (0 when the residuals are all explained by the standard
        errors).

    Raises
    ------
    DesignError
        If the file is missing, lacks a column, or holds fewer levels than curve
        coefficients + 1 of the prior's participant.
    """
    who = prior.participants[0]
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.DictReader(fh)
                    if r.get("participant", who.code) in (who.code, "")]
    except OSError as exc:
        raise DesignError(f"{path}: cannot read the first session's parameters "
                          f"({exc.strerror or exc})") from None
    if not rows:
        raise DesignError(f"{path}: no rows for participant {who.code}")
    out: dict[str, float] = {}
    for name in PARAMETERS:
        need = ("sE", name, _SE_COLUMNS[name], "n_trials")
        missing = [c for c in need if c not in rows[0]]
        if missing:
            raise DesignError(f"{path}: column(s) {', '.join(missing)} missing (give the "
                              "parameters.csv that nmsid identify wrote)")
        data = [(float(r["sE"]), float(r[name]), float(r[_SE_COLUMNS[name]]),
                 float(r["n_trials"])) for r in rows if r[name] not in ("", "nan")]
        cols = [np.array(v) for v in zip(*data, strict=True)] if data else [np.zeros(0)] * 4
        x, y, se, nt = cols
        k = len(who.curves[name].coefficients)
        if len(x) < k + 2:
            raise DesignError(f"{path}: {len(x)} identified level(s) of {name}; at least "
                              f"{k + 2} are needed to measure the scatter about its curve")
        fit = who.curves[name](x)
        rel = y / fit - 1.0
        excess = np.sum(rel ** 2) / (len(x) - k) - np.mean((se / fit) ** 2)
        out[name] = float(np.sqrt(max(excess, 0.0) * np.mean(nt)))
    return PerParameter(**out)


#: A first session whose levels fit (median over levels, ``fit_pct`` of parameters.csv)
#: below this is not second order within what averaging repeats can remove: a second-order
#: participant behind the paper's sensor (Leptrino via a 16-bit A/D, 0.005-0.06 N RMS) and
#: responses of 1 N RMS or more fits >= 98 % with two repeats (bench_identification: 99.2-
#: 99.9 %, with 10/5/5 % scatter between repeats too), while musculoskeletal (Hill-type)
#: elbows fit 80-90 % (bench_musculoskeletal). Below it the best second-order description
#: depends on the excitation itself (a 4 s chirp moves wn and zeta of a MuJoCo elbow by
#: 0.1-0.4 %, a 0.8-8 Hz band by more), so the design keeps the paper's excitation.
SECOND_ORDER_FIT_PCT = 97.0


@dataclass(frozen=True)
class ModelAdequacy:
    """How well the first session's levels fit a second-order model."""

    median_fit_pct: float
    n_levels: int
    second_order: bool
    threshold_pct: float

    def sentence(self) -> str:
        verdict = ("second order within the noise" if self.second_order else
                   "NOT second order: the twin depends on the excitation, so the design "
                   "keeps the paper's excitation (10 s chirp 1-10 Hz, amplitude 0.5) and "
                   "only shortens the lead-in and chooses levels and repeats")
        return (f"first session: median fit {self.median_fit_pct:.1f} % over "
                f"{self.n_levels} level(s) (threshold {self.threshold_pct:g} %): {verdict}")


def adequacy_from_parameters(path, threshold_pct: float = SECOND_ORDER_FIT_PCT
                             ) -> ModelAdequacy:
    """Is the first session (its ``parameters.csv``) second order within the noise?

    Raises
    ------
    DesignError
        If the file is missing or has no ``fit_pct`` column or no fitted level.
    """
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise DesignError(f"{path}: cannot read the first session's parameters "
                          f"({exc.strerror or exc})") from None
    if rows and "fit_pct" not in rows[0]:
        raise DesignError(f"{path}: column fit_pct missing (give the parameters.csv that "
                          "nmsid identify wrote)")
    fits = [float(r["fit_pct"]) for r in rows if r.get("fit_pct") not in ("", "nan", None)]
    fits = [f for f in fits if math.isfinite(f)]
    if not fits:
        raise DesignError(f"{path}: no level with a fit; identify the first session first")
    med = float(np.median(fits))
    return ModelAdequacy(med, len(fits), med >= threshold_pct, float(threshold_pct))
