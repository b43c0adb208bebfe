"""The public gap helpers return frozen result objects whose ``to_dict()`` is the report's
form (issue 30, item 3); the phase-shape reading checked against closed forms."""

import dataclasses

import numpy as np
import pytest

from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose
from nmsid.analysis.gap.evidence import PhaseShape, phase_shape
from nmsid.analysis.gap.localize import (
    FrequencyView,
    LocationTable,
    ResidualSpectrum,
    by_location,
    frequency_view,
    residual_spectrum,
)
from nmsid.analysis.gap.report import FinalParams, build_report, final_params
from nmsid.protocols.effects import Effect


@pytest.fixture(scope="module")
def diag(dead_time_session):
    # one candidate keeps it fast; the helpers under test read any diagnosis
    s = GapSettings(candidates=(Effect.DEAD_TIME,), try_pairs=False, try_muscle=False)
    return diagnose(load_session(dead_time_session), s)


def test_phase_shape_reads_a_pure_dead_time_and_a_pure_lag():
    f = np.linspace(1.0, 10.0, 30)
    L = 0.012
    dead = phase_shape({"f_Hz": f, "phase_error_deg": -360 * f * L,
                        "gain_error_dB": np.zeros_like(f)})
    assert isinstance(dead, PhaseShape)
    assert dead.dead_time_equivalent_s == pytest.approx(L, rel=1e-12)
    assert dead.r2_linear_phase == pytest.approx(1.0, abs=1e-12)
    tau = float(np.geomspace(1e-4, 0.3, 400)[250])  # on phase_shape's grid: found exactly
    lag = phase_shape({"f_Hz": f, "phase_error_deg": -np.degrees(np.arctan(2 * np.pi * f * tau)),
                       "gain_error_dB": -10 * np.log10(1 + (2 * np.pi * f * tau) ** 2)})
    assert lag.lag_equivalent_s == pytest.approx(tau, rel=1e-12)
    assert lag.r2_atan_phase == pytest.approx(1.0, abs=1e-12)
    assert lag.gain_rolloff_expected_for_lag_dB == pytest.approx(lag.gain_error_at_top_dB)
    with pytest.raises(dataclasses.FrozenInstanceError):
        lag.lag_equivalent_s = 0.0  # type: ignore[misc]


def test_result_objects_are_frozen_and_give_the_report_form(diag):
    table = by_location(diag, diag.nominal)
    view = frequency_view(diag, diag.nominal)
    spec = residual_spectrum(diag, diag.nominal)
    fp = final_params(diag)
    for obj, cls in ((table, LocationTable), (view, FrequencyView),
                     (spec, ResidualSpectrum), (fp, FinalParams)):
        assert isinstance(obj, cls)
        assert dataclasses.is_dataclass(obj) and type(obj).__dataclass_params__.frozen
    d = table.to_dict()
    assert list(d) == ["sE", "band", "position", "deviation"]
    assert all(isinstance(v, list) for v in d.values())
    assert len(d["position"]) == int(diag.tested.sum())
    assert set(view.to_dict()) == {"f_Hz", "gain_error_dB", "phase_error_deg", "coherence",
                                   "residual_harmonic_pct", "measured_harmonic_pct"}
    assert set(view.residual_harmonic_pct) == {"1f", "1.5f", "2f", "3f"}
    assert spec.to_dict()["low_share"] == spec.low_share
    # the winner here is the dead time: its parameter, no curve, and the report's best_params
    assert diag.best is not None and diag.best.candidate.effect.value == "dead_time"
    assert fp.curve is None and "_curve" not in fp.to_dict()
    assert fp.to_dict()["L_s"] == pytest.approx(0.030, rel=0.1)
    report = build_report(diag).report
    assert report["best_params"] == fp.to_dict()
    assert report["localization"]["nominal"] == d
    assert report["frequency"]["nominal"] == view.to_dict()
    assert report["low_frequency"]["nominal"] == {
        k: v for k, v in spec.to_dict().items() if k not in ("f_Hz", "power")}
    tf = report["evidence"]["signatures"]["transfer_function"]
    assert tf == phase_shape(view).to_dict()
