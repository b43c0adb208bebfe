"""The muscle twin in the gap diagnosis: template sessions keep the template's verdicts."""

from __future__ import annotations

from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose


def test_template_session_never_goes_to_the_muscle_twin(nominal_session):
    """Second-order data: the template explains it; the muscle twin is not even tried."""
    diag = diagnose(load_session(nominal_session), GapSettings(try_pairs=False))
    assert diag.assessment["verdict"] == "none"
    assert diag.muscle is None and diag.muscle_tried is None
