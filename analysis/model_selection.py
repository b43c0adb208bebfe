"""Model selection across sE: the paper's Results (Tables 1-9) for one or many sessions.

For each parameter (Kp, wn, zeta) and each participant, and for the participant average
at each sE: fit the linear, quadratic and exponential curves (:mod:`nmsid.analysis.curves`) to the
same points, compute AICc, select the lowest, describe the trend. For wn and zeta
(``IdentificationSettings.iqr_parameters``) the paper first removes IQR outliers per
participant, averages the participants per sE, and removes IQR outliers again from the
averages. AICc of each model is summed across participants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nmsid.analysis.curves import CurveFit, Trend, fit_curve, trend_of
from nmsid.analysis.outliers import iqr_fences, iqr_inliers
from nmsid.analysis.settings import PARAMETER_NAMES, IdentificationSettings
from nmsid.protocols.reprs import counted, html_repr, names, short_repr, to_dataframe

AVERAGE_LABEL = "average"


@dataclass
class Point:
    """One (sE, value) point and whether the comparison used it."""

    sE: float
    value: float
    used: bool
    note: str = ""


@dataclass
class ModelComparison:
    """The candidate curves of one parameter for one participant (or the average)."""

    parameter: str
    label: str
    points: list[Point]
    fits: dict[str, CurveFit]
    selected: str | None
    trend: Trend | None
    problems: list[str] = field(default_factory=list)

    @property
    def selected_fit(self) -> CurveFit | None:
        return self.fits.get(self.selected) if self.selected else None

    def __repr__(self) -> str:
        return short_repr("ModelComparison", f"{self.parameter} of {self.label}",
                          f"selected {self.selected or 'none'}",
                          f"{sum(p.used for p in self.points)}/{len(self.points)} points used",
                          f"candidates {', '.join(self.fits)}",
                          counted(len(self.problems), "problem") if self.problems else "")

    _repr_html_ = html_repr

    def used_points(self) -> tuple[np.ndarray, np.ndarray]:
        pts = [(p.sE, p.value) for p in self.points if p.used]
        if not pts:
            return np.empty(0), np.empty(0)
        x, y = zip(*pts, strict=True)
        return np.asarray(x), np.asarray(y)

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v

        return {
            "parameter": self.parameter, "label": self.label,
            "points": [{"sE": p.sE, "value": num(p.value), "used": p.used, "note": p.note}
                       for p in self.points],
            "models": {m: {"coefficients": f.coefficients, "rss": num(f.rss), "n": f.n,
                           "k": f.k, "aicc": num(f.aicc), "selectable": f.selectable,
                           "notes": f.notes} for m, f in self.fits.items()},
            "selected": self.selected,
            "trend": None if self.trend is None else {
                "direction": self.trend.direction, "opens": self.trend.opens,
                "extremum_sE": self.trend.extremum_sE,
                "extremum_value": self.trend.extremum_value,
                "extremum_inside_range": self.trend.extremum_inside,
                "text": self.trend.text},
            "problems": self.problems,
        }


def compare_models(sE, values, parameter: str, label: str,
                   settings: IdentificationSettings | None = None,
                   remove_outliers: bool | None = None) -> ModelComparison:
    """Fit every candidate curve to the same points and select by lowest AICc.

    Parameters
    ----------
    sE, values : array-like
        The points; NaN values (levels not identified) are left out with a note.
    parameter : str
        ``Kp``, ``wn_rad_s`` or ``zeta`` (names the comparison).
    label : str
        Participant code or ``average``.
    settings : IdentificationSettings, optional
        ``models``, ``iqr_k``, ``iqr_parameters``, ``aicc_count_noise_variance``.
    remove_outliers : bool, optional
        Apply the IQR rule first; default: when ``parameter`` is in ``iqr_parameters``.

    Returns
    -------
    ModelComparison
    """
    s = settings or IdentificationSettings()
    x = np.asarray(sE, dtype=float)
    y = np.asarray(values, dtype=float)
    if remove_outliers is None:
        remove_outliers = parameter in s.iqr_parameters
    finite = np.isfinite(y) & np.isfinite(x)
    keep = finite.copy()
    notes = ["" if f else "not identified" for f in finite]
    if remove_outliers and finite.sum() >= 1:
        inl = iqr_inliers(np.where(finite, y, np.nan), s.iqr_k)
        fences = iqr_fences(y[finite], s.iqr_k)
        for i in np.flatnonzero(finite & ~inl):
            notes[i] = (f"IQR outlier (outside [{fences.low:.4g}, {fences.high:.4g}], "
                        f"k = {s.iqr_k:g})")
        keep = finite & inl
    points = [Point(float(a), float(b), bool(k), n)
              for a, b, k, n in zip(x, y, keep, notes, strict=True)]
    xs, ys = x[keep], y[keep]
    fits: dict[str, CurveFit] = {m: fit_curve(m, xs, ys, s.aicc_count_noise_variance)
                                 for m in s.models}
    selectable = {m: f for m, f in fits.items() if f.selectable}
    problems = []
    where = f"{label} {parameter}"
    if not selectable:
        problems.append(f"{where}: {len(xs)} usable point(s); no model is selectable "
                        "(AICc needs n - k - 1 > 0: at least 4 points for linear and "
                        "exponential, 5 for quadratic)")
        return ModelComparison(parameter, label, points, fits, None, None, problems)
    for m, f in fits.items():
        if not f.selectable:
            problems.append(f"{where}: {m} model not selectable ({'; '.join(f.notes)})")
    # lowest AICc; a tie goes to the model with fewer coefficients
    selected = min(selectable, key=lambda m: (selectable[m].aicc, len(selectable[m].coefficients)))
    trend = trend_of(selected, fits[selected].coefficients, float(xs.min()), float(xs.max()))
    return ModelComparison(parameter, label, points, fits, selected, trend, problems)


@dataclass
class ParticipantParameters:
    """Identified parameters of one participant (input of :func:`select_models`)."""

    participant: str
    sE: np.ndarray
    values: dict[str, np.ndarray]
    """Parameter name -> values at ``sE`` (NaN where a level was not identified)."""


def participant_parameters(session_result) -> ParticipantParameters:
    """Collect the parameters of an ``analysis.identify.SessionResult``.

    Levels whose fit did not converge are left out (NaN): their numbers are where the
    search stopped, not estimates.
    """
    sE = np.array([lv.sE for lv in session_result.levels], dtype=float)
    usable = [lv.fit is not None and lv.fit.converged for lv in session_result.levels]
    values = {name: np.array([getattr(lv.fit, name) if ok else np.nan
                              for lv, ok in zip(session_result.levels, usable, strict=True)],
                             dtype=float)
              for name in PARAMETER_NAMES}
    return ParticipantParameters(session_result.participant, sE, values)


@dataclass
class SelectionResult:
    """Every comparison, the AICc sums and the problems met."""

    participants: list[str]
    comparisons: list[ModelComparison]
    aicc_sums: dict[str, dict[str, float]]
    aicc_sum_counts: dict[str, dict[str, int]]
    problems: list[str]
    settings: IdentificationSettings

    def rows(self) -> list[dict]:
        """One dict per comparison: parameter, participant (or the average), the model
        selected and its AICc."""
        out = []
        for c in self.comparisons:
            fit = c.selected_fit
            out.append({"parameter": c.parameter, "label": c.label, "selected": c.selected,
                        "aicc": fit.aicc if fit is not None else float("nan"),
                        "points_used": sum(p.used for p in c.points),
                        "points": len(c.points)})
        return out

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        chosen = [f"{c.parameter}: {c.selected or 'none'}" for c in self.comparisons
                  if c.label == (self.participants[0] if len(self.participants) == 1
                                 else AVERAGE_LABEL)]
        return short_repr("SelectionResult", names(self.participants),
                          counted(len(self.comparisons), "comparison"), "; ".join(chosen),
                          counted(len(self.problems), "problem") if self.problems else "")

    _repr_html_ = html_repr

    def comparison(self, parameter: str, label: str) -> ModelComparison | None:
        for c in self.comparisons:
            if c.parameter == parameter and c.label == label:
                return c
        return None

    def to_dict(self) -> dict:
        return {
            "format": "nmsid-model-selection", "format_version": 1,
            "participants": self.participants,
            "settings": self.settings.as_dict(),
            "comparisons": [c.to_dict() for c in self.comparisons],
            "aicc_sums": self.aicc_sums,
            "aicc_sum_counts": self.aicc_sum_counts,
            "problems": self.problems,
        }


def merge_sessions(people: list[ParticipantParameters]) -> list[ParticipantParameters]:
    """One entry per participant code, in order of first appearance.

    Several sessions of one participant (the same code) are one participant: at each sE
    the parameter is the mean of that participant's sessions that identified it (a level
    one session lacks is taken from the others), so the person counts once in the group
    average and in the AICc sums (issue 39: ``P01`` and ``P01#2`` were two people).
    """
    by_code: dict[str, list[ParticipantParameters]] = {}
    for p in people:
        by_code.setdefault(p.participant, []).append(p)
    merged = []
    for code, group in by_code.items():
        if len(group) == 1:
            merged.append(group[0])
            continue
        grid = sorted({round(float(x), 6) for p in group for x in p.sE})
        values = {}
        for name in PARAMETER_NAMES:
            table = np.full((len(group), len(grid)), np.nan)
            for i, p in enumerate(group):
                for x, v in zip(p.sE, p.values[name], strict=True):
                    table[i, grid.index(round(float(x), 6))] = v
            n = np.sum(np.isfinite(table), axis=0)
            values[name] = np.where(n > 0, np.nansum(table, axis=0) / np.maximum(n, 1),
                                    np.nan)
        merged.append(ParticipantParameters(code, np.array(grid), values))
    return merged


def select_models(participants, settings: IdentificationSettings | None = None
                  ) -> SelectionResult:
    """Model selection for each participant and for the participant average.

    Parameters
    ----------
    participants : sequence of ParticipantParameters or SessionResult
        One entry per session; the sessions of one participant code are one participant
        (:func:`merge_sessions`).
    settings : IdentificationSettings, optional

    Returns
    -------
    SelectionResult
    """
    s = settings or IdentificationSettings()
    people = merge_sessions([p if isinstance(p, ParticipantParameters)
                             else participant_parameters(p) for p in participants])
    labels = [p.participant for p in people]
    comparisons: list[ModelComparison] = []
    problems: list[str] = []
    grid = sorted({round(float(x), 6) for p in people for x in p.sE})
    sums: dict[str, dict[str, float]] = {name: dict.fromkeys(s.models, 0.0)
                                         for name in PARAMETER_NAMES}
    counts: dict[str, dict[str, int]] = {name: dict.fromkeys(s.models, 0)
                                         for name in PARAMETER_NAMES}
    for name in PARAMETER_NAMES:
        cleaned = np.full((len(people), len(grid)), np.nan)
        for i, (p, label) in enumerate(zip(people, labels, strict=True)):
            c = compare_models(p.sE, p.values[name], name, label, s)
            comparisons.append(c)
            problems.extend(c.problems)
            for m, f in c.fits.items():
                if f.selectable and f.aicc is not None:
                    sums[name][m] += f.aicc
                    counts[name][m] += 1
            for pt in c.points:
                if pt.used:
                    cleaned[i, grid.index(round(pt.sE, 6))] = pt.value
        with np.errstate(all="ignore"):
            n_per_level = np.sum(np.isfinite(cleaned), axis=0)
            average = np.where(n_per_level > 0, np.nansum(cleaned, axis=0) /
                               np.maximum(n_per_level, 1), np.nan)
        avg = compare_models(np.array(grid), average, name, AVERAGE_LABEL, s)
        comparisons.append(avg)
        problems.extend(avg.problems)
        for m in s.models:
            if 0 < counts[name][m] < len(people):
                problems.append(f"AICc sum of the {m} model for {name} covers "
                                f"{counts[name][m]} of {len(people)} participants")
    return SelectionResult(labels, comparisons, sums, counts, problems, s)
