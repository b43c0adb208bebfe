"""The gap verdict's sentence speaks the session's unit (N m at a knee or an ankle)."""

from nmsid.analysis.gap.verdict import sentence

REMAINING = {"beyond_noise_pct_typical": 1.0, "concentrated_in": ["t003"],
             "where": {"baseline_steps": [{"trial": "t003", "share_of_excess_pct": 90.0,
                                           "height_N": 2.5, "t_s": 1.2}]}}


def test_a_baseline_step_is_told_in_the_sessions_unit():
    knee = sentence("named", "dead_time", {"beyond_noise_pct_typical": 2.0}, REMAINING,
                    unit="N m")
    assert "baseline step of +2.50 N m at 1.2 s" in knee
    elbow = sentence("named", "dead_time", {"beyond_noise_pct_typical": 2.0}, REMAINING)
    assert "baseline step of +2.50 N at 1.2 s" in elbow
