"""Model selection: hand-computed AICc and selection, shared points, IQR, group sums."""

import math

import numpy as np
import pytest

from nmsid.analysis.model_selection import (
    AVERAGE_LABEL,
    ParticipantParameters,
    compare_models,
    select_models,
)
from nmsid.analysis.settings import IdentificationSettings


def test_hand_computed_selection_linear_beats_quadratic():
    # y = [0,1,0,1,0] at x = 0..4: linear RSS = 1.2 (slope 0), quadratic RSS = 1.2 - 4/14
    s = IdentificationSettings(models=("linear", "quadratic"))
    c = compare_models([0, 1, 2, 3, 4], [0, 1, 0, 1, 0], "Kp", "P01", s)
    lin, quad = c.fits["linear"], c.fits["quadratic"]
    assert lin.rss == pytest.approx(1.2)
    assert quad.rss == pytest.approx(1.2 - 4.0 / 14.0)
    assert lin.aicc == pytest.approx(5 * math.log(1.2 / 5) + 4 + 12 / 2)       # 2.8644
    assert quad.aicc == pytest.approx(5 * math.log((1.2 - 4 / 14) / 5) + 6 + 24 / 1)
    assert c.selected == "linear"
    assert c.trend.direction == "constant"


def test_quadratic_selected_when_curved_and_trend_reports_extremum():
    x = np.linspace(0.3, 1.0, 15)
    y = 40 - 60 * (x - 0.6) ** 2 + np.random.default_rng(0).normal(0, 0.2, 15)
    c = compare_models(x, y, "wn_rad_s", "P01")
    assert c.selected == "quadratic"
    assert c.trend.opens == "down" and c.trend.extremum_inside
    assert c.trend.extremum_sE == pytest.approx(0.6, abs=0.02)
    ref = np.polyfit(x, y, 2)
    rss = float(np.sum((y - np.polyval(ref, x)) ** 2))
    assert c.fits["quadratic"].rss == pytest.approx(rss, rel=1e-9)
    n, k = 15, 3
    assert c.fits["quadratic"].aicc == pytest.approx(
        n * math.log(rss / n) + 2 * k + 2 * k * (k + 1) / (n - k - 1))


def test_all_models_use_the_same_points_after_iqr():
    x = np.linspace(0.3, 1.0, 15)
    y = 30 + 10 * x + np.random.default_rng(2).normal(0, 0.1, 15)
    y[4] = 200.0                             # an outlier
    y[9] = np.nan                            # a level not identified
    c = compare_models(x, y, "wn_rad_s", "P01")
    assert {f.n for f in c.fits.values()} == {13}
    assert not c.points[4].used and "IQR outlier" in c.points[4].note
    assert not c.points[9].used and c.points[9].note == "not identified"
    assert c.selected is not None
    # Kp is not cleaned by default (paper: IQR for wn and zeta only)
    k = compare_models(x, y, "Kp", "P01")
    assert {f.n for f in k.fits.values()} == {14}


def test_too_few_levels_say_so_and_do_not_crash():
    c = compare_models([0.3, 0.5, 0.7, 0.9], [1.0, 2.0, 2.5, 3.1], "Kp", "P01")
    assert c.selected in ("linear", "exponential")
    assert any("quadratic model not selectable" in p for p in c.problems)
    d = compare_models([0.3, 0.5, 0.7], [1.0, 2.0, 2.5], "Kp", "P01")
    assert d.selected is None and "no model is selectable" in d.problems[0]


def test_group_average_and_aicc_sums():
    x = np.linspace(0.3, 1.0, 15)
    rng = np.random.default_rng(4)
    people = [ParticipantParameters(f"P{i}", x, {
        "Kp": 2 * np.exp(1.5 * x) * (1 + 0.1 * i) + rng.normal(0, 0.05, 15),
        "wn_rad_s": 20 + 10 * x + i + rng.normal(0, 0.3, 15),
        "zeta": 0.5 + 0.1 * x + rng.normal(0, 0.01, 15)}) for i in range(3)]
    people[1].values["wn_rad_s"][3] = 500.0          # participant-level outlier
    sel = select_models(people)
    assert sel.participants == ["P0", "P1", "P2"]
    for name in ("Kp", "wn_rad_s", "zeta"):
        for m in ("linear", "quadratic", "exponential"):
            per = [sel.comparison(name, p).fits[m].aicc for p in sel.participants]
            assert sel.aicc_sums[name][m] == pytest.approx(sum(per))
            assert sel.aicc_sum_counts[name][m] == 3
    avg = sel.comparison("wn_rad_s", AVERAGE_LABEL)
    # the outlier of P1 is left out of the average at that level
    expected = np.mean([people[0].values["wn_rad_s"][3], people[2].values["wn_rad_s"][3]])
    assert avg.points[3].value == pytest.approx(expected)
    kp_avg = sel.comparison("Kp", AVERAGE_LABEL)
    assert kp_avg.points[0].value == pytest.approx(np.mean([p.values["Kp"][0] for p in people]))
    assert kp_avg.selected == "exponential"
    d = sel.to_dict()
    assert d["format"] == "nmsid-model-selection" and len(d["comparisons"]) == 12


def test_sessions_of_one_participant_are_one_participant():
    """Issue 39: two sessions of P1 were the two participants "P1" and "P1#2"."""
    x = np.linspace(0.3, 1.0, 6)
    p = ParticipantParameters("P1", x, dict.fromkeys(("Kp", "wn_rad_s", "zeta"), 1 + x))
    q = ParticipantParameters("P1", x[:4], dict.fromkeys(("Kp", "wn_rad_s", "zeta"), 3 + x[:4]))
    r = ParticipantParameters("P2", x, dict.fromkeys(("Kp", "wn_rad_s", "zeta"), 2 + x))
    sel = select_models([p, r, q])
    assert sel.participants == ["P1", "P2"]
    kp = sel.comparison("Kp", "P1")
    values = {round(pt.sE, 6): pt.value for pt in kp.points}
    # the mean of the two sessions where both have the level, the one session elsewhere
    assert values[round(x[0], 6)] == pytest.approx(2 + x[0])
    assert values[round(x[5], 6)] == pytest.approx(1 + x[5])
