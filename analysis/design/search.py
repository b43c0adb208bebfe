"""The least stimulation that reaches a target precision: search over candidate protocols.

Targets:

* ``paper``: every predicted curve standard error (per participant, parameter and paper
  level) and every derived quantity's (extremum, rate, slope) at most ``1 + tolerance``
  times the paper protocol's, and the predicted probability of selecting the right curve
  family at least the paper's minus ``selection_tolerance``;
* an SD specification, ``"Kp=0.05,wn_rad_s=0.03,zeta=0.03"``: the largest relative curve
  standard error of each parameter at most the given fraction (and the same selection
  rule against the paper protocol).

Candidates are tried in order of stimulation seconds (then session length); the first that
meets the target is the proposal. If none does, the result says so and gives the
candidate closest to the target.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from nmsid.analysis.design.candidates import Candidate, paper_candidate, search_space
from nmsid.analysis.design.errors import DesignError
from nmsid.analysis.design.predict import (
    Prediction,
    Predictor,
    SdRatio,
    SelectionAccuracy,
    derived_ratio,
    relative_curve_se,
    sd_ratio,
)
from nmsid.analysis.design.prior import PARAMETERS, PerParameter

#: "No worse than the paper" allows this relative excess of a predicted standard error:
#: a 2 % difference is far below what a study of ten participants can detect, and below
#: the +-20 % to which the bound itself is checked (bench_identification).
DEFAULT_TOLERANCE = 0.02

#: ... and this shortfall of the predicted selection accuracy (about twice the
#: Monte-Carlo standard error with 20 participants x 3 parameters x 100 draws).
DEFAULT_SELECTION_TOLERANCE = 0.01


@dataclass
class Target:
    """What the proposal must reach (see the module docstring)."""

    kind: str
    """``paper`` or ``sd``."""
    sd: dict = field(default_factory=dict)
    tolerance: float = DEFAULT_TOLERANCE
    selection_tolerance: float = DEFAULT_SELECTION_TOLERANCE

    def describe(self) -> str:
        if self.kind == "paper":
            return (f"no worse than the paper's protocol (standard errors <= "
                    f"{1 + self.tolerance:g} x, selection accuracy >= paper - "
                    f"{self.selection_tolerance:g})")
        return "relative curve SE " + ", ".join(f"{k} <= {v:g}" for k, v in self.sd.items())


def parse_target(text: str, tolerance: float = DEFAULT_TOLERANCE) -> Target:
    """``paper`` or ``Kp=0.05,wn_rad_s=0.03,zeta=0.03`` (relative SDs; ``wn`` accepted).

    Raises
    ------
    DesignError
        Naming the bad part and what is valid.
    """
    text = (text or "").strip()
    if text == "paper":
        return Target("paper", tolerance=tolerance)
    sd = {}
    for part in text.split(","):
        if "=" not in part:
            raise DesignError(f"--target {text!r}: give 'paper' or an SD specification like "
                              "'Kp=0.05,wn_rad_s=0.03,zeta=0.03' (relative SDs)")
        name, _, value = part.partition("=")
        name = {"wn": "wn_rad_s"}.get(name.strip(), name.strip())
        if name not in PARAMETERS:
            raise DesignError(f"--target: unknown parameter {name!r}; valid: "
                              + ", ".join(PARAMETERS))
        try:
            v = float(value)
        except ValueError:
            raise DesignError(f"--target: {name}={value!r} is not a number") from None
        if not 0 < v < 10:
            raise DesignError(f"--target: {name}={v:g}: a relative SD in (0, 10)")
        sd[name] = v
    return Target("sd", sd=sd, tolerance=tolerance)


@dataclass
class Evaluation:
    """One candidate against the target."""

    candidate: Candidate
    prediction: Prediction
    ratio: SdRatio
    derived_ratio: float
    relative_se: PerParameter
    meets_precision: bool
    selection: SelectionAccuracy | None = None
    meets_selection: bool | None = None

    @property
    def meets(self) -> bool:
        return self.meets_precision and bool(self.meets_selection)


@dataclass
class DesignResult:
    """The proposal, the paper's protocol under the same prior, and how the search went."""

    target: Target
    paper: Evaluation
    proposal: Evaluation
    found: bool
    n_evaluated: int
    notes: list[str] = field(default_factory=list)


def _precision_ok(target: Target, ratio: SdRatio, dratio: float,
                  rel: PerParameter) -> bool:
    if target.kind == "paper":
        return ratio.max <= 1 + target.tolerance and dratio <= 1 + target.tolerance
    return all(getattr(rel, k) <= v for k, v in target.sd.items())


def evaluate(predictor: Predictor, c: Candidate, paper: Prediction, target: Target
             ) -> Evaluation:
    pred = predictor.predict(c)
    ratio = sd_ratio(pred, paper)
    dr = derived_ratio(pred, paper)
    rel = relative_curve_se(pred)
    return Evaluation(c, pred, ratio, dr, rel, _precision_ok(target, ratio, dr, rel))


def design(predictor: Predictor, target: Target, candidates: list[Candidate] | None = None,
           *, draws: int = 100, seed: int = 0, max_stimulation_s: float | None = None,
           paper: Candidate | None = None, on_candidate=None) -> DesignResult:
    """Search ``candidates`` (default :func:`search_space`) for the least stimulation.

    Parameters
    ----------
    predictor : Predictor
    target : Target
    candidates : list of Candidate, optional
    draws : int
        Monte-Carlo draws per prior participant for the selection accuracy.
    seed : int
        Seeds the Monte-Carlo draws (the same for every candidate).
    max_stimulation_s : float, optional
        Candidates above this are not tried.
    paper : Candidate, optional
        The reference protocol (default the paper's).
    on_candidate : callable, optional
        Called with no argument after each candidate evaluated (progress).
    """
    ref = paper or paper_candidate()
    paper_pred = predictor.predict(ref)
    paper_eval = Evaluation(ref, paper_pred, sd_ratio(paper_pred, paper_pred), 1.0,
                            relative_curve_se(paper_pred), True)
    paper_eval.selection = predictor.selection_accuracy(paper_pred, draws, seed)
    paper_eval.meets_selection = True
    need = paper_eval.selection.overall - target.selection_tolerance
    cands = candidates if candidates is not None else search_space()
    best_miss: Evaluation | None = None
    n = 0
    for c in sorted(cands, key=lambda c: (c.stimulation_s, c.session_s, -c.rE_amplitude)):
        if max_stimulation_s is not None and c.stimulation_s > max_stimulation_s:
            break
        try:
            c.config()
        except ValueError:
            continue      # a candidate the configuration refuses is never proposed
        n += 1
        if on_candidate is not None:
            on_candidate()
        ev = evaluate(predictor, c, paper_pred, target)
        if best_miss is None or ev.ratio.max < best_miss.ratio.max:
            best_miss = ev
        if not ev.meets_precision:
            continue
        ev.selection = predictor.selection_accuracy(ev.prediction, draws, seed)
        ev.meets_selection = ev.selection.overall >= need
        if ev.meets_selection:
            return DesignResult(target, paper_eval, ev, True, n)
    notes = ["no candidate met the target; the proposal is the candidate with the smallest "
             "largest standard-error ratio"]
    if best_miss is None:
        raise DesignError("no candidate protocol to evaluate (every one was refused by the "
                          "configuration checks)")
    best_miss.selection = predictor.selection_accuracy(best_miss.prediction, draws, seed)
    best_miss.meets_selection = best_miss.selection.overall >= need
    return DesignResult(target, paper_eval, best_miss, False, n, notes)
