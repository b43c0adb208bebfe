"""A virtual participant built from a twin file runs that twin."""

import json

import numpy as np
import pytest
from scipy import signal

from nmsid.protocols.effects import chain_of
from nmsid.sim_backends import make_sim_rig, participant_from_twin
from nmsid.sim_backends.direct_drive import chirp_rE, currents_for, run_waveform, waveform
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.filters import second_order_zoh
from nmsid.sim_backends.population import make_population
from nmsid.sim_backends.sensor import SensorModel
from nmsid.sim_backends.twin import write_twin

TWIN = {
    "format": "nmsid-twin", "format_version": 1, "participant": "P01",
    "source": ["sessions/P01.h5"],
    "calibration": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5, "Ifmax_mA": 8.0,
                    "Fmin_N": 0.5, "Fmax_N": 5.0},
    "sE_range": [0.30, 1.00],
    "parameters": {
        "Kp": {"model": "exponential", "coefficients": [0.9, 1.6]},
        "wn_rad_s": {"model": "quadratic", "coefficients": [10.0, 40.0, -25.0]},
        "zeta": {"model": "linear", "coefficients": [0.4, 0.3]},
    },
    "offset_N": {"model": "linear", "coefficients": [0.1, 0.2]},
    "effects": [{"name": "fatigue", "params": {"shape": "exponential", "gain_loss_pct": 10.0,
                                               "reference_stim_s": 675.0}}],
}


def test_twin_participant_reproduces_the_twin_model_exactly(tmp_path):
    path = tmp_path / "twin.json"
    twin = dict(TWIN, effects=[])
    path.write_text(json.dumps(twin))
    p = participant_from_twin(path, sensor=SensorModel.ideal())
    assert p.code == "P01" and p.ramp_calibration().Iemax_mA == 9.5
    sE = 0.55
    rE = chirp_rE()
    rig = make_sim_rig(p, connect=True)
    force, _ = run_waveform(rig, waveform(*currents_for(p.calibration, sE, rE)))
    Kp = 0.9 * np.exp(1.6 * sE)
    wn = 10 + 40 * sE - 25 * sE ** 2
    zeta = 0.4 + 0.3 * sE
    assert tuple(p.true_parameters(sE)) == pytest.approx((Kp, wn, zeta))
    b, a = second_order_zoh(wn, zeta, 2000.0)
    y = signal.lfilter(b, a, Kp * (rE - 0.5))
    offset = 0.1 + 0.2 * sE
    steady = np.arange(rE.size) > 2000          # the offset enters through the dynamics
    assert np.max(np.abs(force - offset - y)[steady]) < 2e-3


def test_twin_round_trip_and_effects(tmp_path):
    p = participant_from_twin(TWIN)
    assert p.effect_truth() == TWIN["effects"]
    assert chain_of(p.effects).gain(675.0) == pytest.approx(0.9)
    q = make_population(1, seed=4)[0]
    write_twin(q, tmp_path / "q.json")
    back = participant_from_twin(tmp_path / "q.json", sensor=q.sensor, seed=q.seed)
    assert back == q
    with pytest.raises(FileExistsError):
        write_twin(q, tmp_path / "q.json")


def test_off_grid_calibration_is_snapped_onto_the_ramp_grid():
    twin = json.loads(json.dumps(TWIN))
    twin["calibration"]["Iemin_mA"] = 2.2
    p = participant_from_twin(twin)
    assert p.calibration.Iemin_mA == 2.5 and p.ramp_calibration() == p.calibration


@pytest.mark.parametrize("change,match", [
    ({"format": "other"}, "nmsid-twin"),
    ({"format_version": 2}, "format_version"),
    ({"parameters": {"Kp": {"model": "cubic", "coefficients": [1, 2, 3, 4]}}}, "cubic"),
    ({"parameters": {"Kp": {"model": "linear", "coefficients": [1.0]}}}, "2 coefficients"),
    ({"effects": [{"name": "tremor", "params": {}}]}, "tremor"),
    ({"parameters": {"Kp": {"model": "linear", "coefficients": [1.0, 1.0]},
                     "wn_rad_s": {"model": "linear", "coefficients": [-50.0, 1.0]},
                     "zeta": {"model": "constant", "coefficients": [0.5]}}}, "wn_rad_s"),
])
def test_bad_twins_are_refused_with_a_message_naming_the_problem(change, match):
    twin = dict(TWIN, **change)
    with pytest.raises(SimConfigError, match=match):
        participant_from_twin(twin)


def test_a_twin_without_calibration_is_refused_naming_what_it_lacks():
    """Issue 39: a group-average twin (no calibration) gave `calibration needs numeric
    Iemin_mA, ... (KeyError('Iemin_mA'))`."""
    import pytest

    from nmsid.sim_backends.errors import SimConfigError
    from nmsid.sim_backends.participant import default_participant
    from nmsid.sim_backends.twin import participant_from_twin

    data = default_participant().to_twin()
    with pytest.raises(SimConfigError, match="has no calibration .*twin_<participant>.json"):
        participant_from_twin(dict(data, calibration={}))
    bad = dict(data, calibration=dict(data["calibration"], Ifmax_mA="eight"))
    with pytest.raises(SimConfigError, match=r"calibration.Ifmax_mA is 'eight'; .* a number"):
        participant_from_twin(bad)
