"""Control design from the twin: margins against closed forms, the plant, the controllers."""

import json
import math

import numpy as np
import pytest

from nmsid.analysis.control.controllers import (
    PIDController,
    RelayExperiment,
    TwinController,
    TwinControllerSettings,
    relay_analysis,
    ziegler_nichols_pid,
)
from nmsid.analysis.control.design import (
    ControllerDesign,
    design_controller,
    loop_responses,
    pi_tuning,
    rmse_pct_of_range,
    simulate_tracking,
)
from nmsid.analysis.control.errors import ControlDesignError, ControllerFileError
from nmsid.analysis.control.margins import stability_margins
from nmsid.analysis.control.plant import SecondOrderPlant
from nmsid.analysis.control.targets import Target, default_targets, load_target_csv
from nmsid.analysis.twin import Twin
from nmsid.errors import UserError
from nmsid.sim_backends.participant import default_participant


@pytest.fixture(scope="module")
def twin():
    return Twin.from_dict(default_participant().to_twin())


@pytest.mark.parametrize("K, T", [(2.0, 0.1), (5.0, 0.05), (1.0, 0.5)])
def test_margins_of_an_integrator_with_delay_match_the_closed_form(K, T):
    m = stability_margins(lambda w: K * np.exp(-1j * w * T) / (1j * w))
    assert m.crossover_rad_s == pytest.approx(K, rel=1e-6)
    assert m.phase_margin_deg == pytest.approx(90 - math.degrees(K * T), abs=1e-4)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / (2 * T), rel=1e-6)
    assert m.gain_margin == pytest.approx(math.pi / (2 * K * T), rel=1e-6)
    assert m.delay_margin_s == pytest.approx(math.radians(m.phase_margin_deg) / K, rel=1e-6)


def test_margins_of_a_third_order_loop_match_the_closed_form():
    K = 2.0
    m = stability_margins(lambda w: K / ((1j * w) * (1j * w + 1) * (1j * w + 2)))
    assert m.phase_crossover_rad_s == pytest.approx(math.sqrt(2), rel=1e-6)
    assert m.gain_margin == pytest.approx(6 / K, rel=1e-6)
    # |L| = 1: w^2 (w^2 + 1)(w^2 + 4) = K^2, a cubic in w^2
    roots = np.roots([1, 5, 4, -K * K])
    wc = math.sqrt(max(r.real for r in roots if abs(r.imag) < 1e-12))
    assert m.crossover_rad_s == pytest.approx(wc, rel=1e-6)
    pm = 90 - math.degrees(math.atan(wc) + math.atan(wc / 2))
    assert m.phase_margin_deg == pytest.approx(pm, abs=1e-4)


def test_no_phase_crossover_gives_infinite_gain_margin():
    m = stability_margins(lambda w: 3.0 / (1j * w + 1))
    assert math.isinf(m.gain_margin) and m.phase_margin_deg == pytest.approx(
        180 - math.degrees(math.atan(math.sqrt(8))), abs=1e-4)


def test_zoh_plant_matches_the_closed_form_step_response():
    p = SecondOrderPlant(Kp=4.0, wn_rad_s=20.0, zeta=0.5)
    Ts = 0.005
    y = p.simulate(np.full(200, 0.25), Ts)
    t = np.arange(200) * Ts
    wd = 20 * math.sqrt(1 - 0.25)
    exact = 4 * 0.25 * (1 - np.exp(-10 * t) * (np.cos(wd * t) + 0.5 / math.sqrt(0.75)
                                                * np.sin(wd * t)))
    assert np.allclose(y, exact, atol=1e-12)


def test_lambda_rule_gives_an_integrator_loop_of_time_constant_lambda():
    p = SecondOrderPlant(3.0, 25.0, 0.6)
    Kc, Ti, lam = pi_tuning(p, 0.0075, 0.1)
    _, nominal = loop_responses(p, Kc, Ti, 0.0075)
    w = 1e-3
    assert abs(nominal(np.array([w]))[0]) == pytest.approx(1 / (lam * w), rel=1e-3)
    assert Ti == pytest.approx(2 * 0.6 / 25.0)


def test_the_smith_loop_with_an_exact_model_has_the_nominal_crossover():
    """With a perfect model the Smith predictor takes the delay out of the loop:
    T = C G0 e^{-sD} / (1 + C G0) for the implemented loop."""
    p = SecondOrderPlant(3.0, 25.0, 0.6)
    Kc, Ti, _ = pi_tuning(p, 0.05, 0.1)
    impl, nominal = loop_responses(p, Kc, Ti, 0.05)
    w = np.logspace(-1, 2, 50)
    Li, Ln = impl(w), nominal(w)
    T_impl = Li / (1 + Li)
    T_expected = Ln * np.exp(-1j * w * 0.05) / (1 + Ln)
    assert np.allclose(T_impl, T_expected, rtol=1e-9, atol=1e-12)


def test_design_picks_the_fastest_sE_and_reports_every_level(twin):
    d = design_controller(twin, levels=5)
    assert len(d.levels) == 5
    wn = [lv.wn_rad_s for lv in d.levels]
    assert d.plant["wn_rad_s"] == pytest.approx(max(wn))
    for lv in d.levels:
        assert lv.margins["phase_margin_deg"] > 30 and lv.margins["gain_margin"] > 2
        assert set(lv.predicted_rmse_pct) == {t.name for t in d.targets()}


def test_twin_controller_tracks_the_twin_at_half_the_relay_pid_error(twin):
    d = design_controller(twin, levels=2)
    Ts = 1 / d.update_Hz
    plant = d.plant_model
    relay = RelayExperiment(0.15, 0.05, Ts, d.queue)
    res = relay_analysis(simulate_tracking(relay, plant, np.zeros(1200), Ts), Ts, 0.15, 0.05)
    for t in d.targets():
        r = t.samples(d.update_Hz)
        skip = int(t.lead_s * d.update_Hz)
        y = simulate_tracking(d.make_controller(), plant, r, Ts)
        yb = simulate_tracking(PIDController(ziegler_nichols_pid(res), Ts, d.queue), plant,
                               r, Ts)
        twin_err = rmse_pct_of_range(y, r, skip)
        assert twin_err < 0.5 * rmse_pct_of_range(yb, r, skip), t.name
        if t.kind == "sine":
            assert twin_err < 2.0


def test_trial_to_trial_learning_reduces_the_error_of_a_repeated_target():
    true = SecondOrderPlant(3.0, 20.0, 0.5, L_s=0.02)
    wrong = SecondOrderPlant(4.2, 26.0, 0.5, L_s=0.02)    # the twin is 40 % off in Kp
    Ts = 0.005
    r = default_targets(-1.0, 1.0)[-1].samples(1 / Ts)     # the 2 Hz sine

    def errors(gain):
        c = TwinController(TwinControllerSettings(wrong, 0.05, 0.05, 0.02, gain), Ts, 2)
        out = []
        for _ in range(4):
            y = simulate_tracking(c, true, r, Ts, target_id="sine")
            out.append(rmse_pct_of_range(y, r, 200))
            c.finish(y)
        return out

    learned, fixed = errors(0.5), errors(0.0)
    assert fixed[0] == pytest.approx(fixed[-1], rel=1e-9)   # without learning: no change
    assert learned[0] == pytest.approx(fixed[0], rel=1e-9)
    assert learned[-1] < 0.5 * learned[0]


def test_anti_windup_holds_the_integrator_while_saturated():
    p = SecondOrderPlant(2.0, 20.0, 0.5)
    s = TwinControllerSettings(p, Kc=0.2, Ti_s=0.05, smoothing_s=0.01)
    c = TwinController(s, 0.005, 2)
    c.start(np.full(400, 5.0))   # far beyond Kp / 2: saturated at rE = 1 throughout
    for j in range(300):
        u = c.step(j, 0.0)
    assert u == 1.0
    I_sat = c.I
    # the integrator stopped growing once saturated (no windup), so it recovers at once
    for j in range(300, 310):
        c.step(j, 0.0)
    assert c.I == I_sat
    s2 = TwinControllerSettings(p, Kc=0.2, Ti_s=0.05, smoothing_s=0.01)
    c2 = TwinController(s2, 0.005, 2)
    c2.start(np.full(400, 0.5))
    for j in range(50):
        c2.step(j, 0.0)
    assert c2.I > 0      # unsaturated: the integrator integrates


def test_relay_analysis_finds_amplitude_period_and_ultimate_gain():
    Ts, period, a = 0.005, 0.2, 0.3
    t = np.arange(1200) * Ts
    y = 1.0 + a * np.sin(2 * np.pi * t / period)
    r = relay_analysis(y, Ts, d=0.15, eps_N=0.0)
    assert r.period_s == pytest.approx(period, rel=1e-3)
    assert r.amplitude_N == pytest.approx(a, rel=1e-2)
    assert r.ultimate_gain == pytest.approx(4 * 0.15 / (math.pi * a), rel=1e-2)
    g = ziegler_nichols_pid(r)
    assert (g.Kc, g.Ti_s, g.Td_s) == pytest.approx((0.6 * r.ultimate_gain, 0.1, 0.025),
                                                   rel=1e-9)
    with pytest.raises(ControlDesignError, match="did not oscillate"):
        relay_analysis(np.linspace(0, 1, 500), Ts, 0.15, 0.0)


def test_relay_on_the_twin_oscillates_and_tunes_a_stable_pid(twin):
    d = design_controller(twin, levels=2)
    Ts = 1 / d.update_Hz
    relay = RelayExperiment(0.15, 0.05, Ts, d.queue)
    y = simulate_tracking(relay, d.plant_model, np.zeros(1200), Ts)
    res = relay_analysis(y, Ts, 0.15, 0.05)
    assert res.n_periods > 5
    pid = PIDController(ziegler_nichols_pid(res), Ts, d.queue)
    r = default_targets(-1, 1)[0].samples(d.update_Hz)
    yb = simulate_tracking(pid, d.plant_model, r, Ts)
    assert np.all(np.isfinite(yb)) and rmse_pct_of_range(yb, r, 200) < 50


def test_controller_json_round_trips_and_bad_files_are_one_line(tmp_path, twin):
    d = design_controller(twin, levels=2)
    path = tmp_path / "controller.json"
    d.save(path)
    back = ControllerDesign.load(path)
    assert back.Kc == d.Kc and back.plant == d.plant and back.force_range_N == d.force_range_N
    data = json.loads(path.read_text())
    data["Kc"] = -1.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(ControllerFileError, match="Kc"):
        ControllerDesign.load(bad)
    with pytest.raises(UserError, match="no such controller file"):
        ControllerDesign.load(tmp_path / "absent.json")
    bad.write_text("{")
    with pytest.raises(UserError, match="not a readable"):
        ControllerDesign.load(bad)


def test_design_refuses_settings_out_of_range(twin):
    with pytest.raises(ControlDesignError, match="outside the twin's tested range"):
        design_controller(twin, sE=1.5)
    with pytest.raises(ControlDesignError, match="update rate"):
        design_controller(twin, update_Hz=1e5)


def test_targets_default_within_range_and_csv_errors(tmp_path):
    ts = default_targets(-2.0, 2.0)
    assert {t.kind for t in ts} == {"step", "ramp", "sine"}
    assert {t.params["f_Hz"] for t in ts if t.kind == "sine"} == {0.2, 0.5, 1.0, 2.0}
    for t in ts:
        r = t.samples(200.0)
        assert r.min() >= -2.0 - 1e-12 and r.max() <= 2.0 + 1e-12
        assert Target.from_json(t.to_json()) == t
    good = tmp_path / "mine.csv"
    good.write_text("t_s,force_N\n0,0\n1,1\n2,0\n", encoding="utf-8")
    t = load_target_csv(good)
    assert t.force_at(np.array([1.0 + t.lead_s]))[0] == 1.0
    for text, words in [("time,force\n0,1\n1,2\n", "header"),
                        ("t_s,force_N\n0,1\n", "at least 2 rows"),
                        ("t_s,force_N\n0,1\n0,2\n", "increase strictly"),
                        ("t_s,force_N\n0,1\n1,x\n", "not numbers")]:
        good.write_text(text, encoding="utf-8")
        with pytest.raises(ControllerFileError, match=words):
            load_target_csv(good)
