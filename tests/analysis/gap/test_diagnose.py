"""End to end on sessions with known answers (small: 5 sE x 3 repeats)."""

import json

import numpy as np
import pytest

from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.diagnose import GapSettings, diagnose, effective_fraction

REQUIRED = ("best_effect", "ranking", "heldout", "localization")


@pytest.fixture(scope="module")
def dead_report(dead_time_session, tmp_path_factory):
    """``nmsid gap`` through the command line (figures included)."""
    from nmsid.cli import main
    out = tmp_path_factory.mktemp("gap_dead")
    assert main(["gap", str(dead_time_session), "--out", str(out)]) == 0
    return out, json.loads((out / "gap_report.json").read_text())


def test_dead_time_session_is_diagnosed_as_dead_time(dead_report):
    _, rep = dead_report
    assert rep["best_effect"] == "dead_time"
    assert rep["best_params"]["L_s"] == pytest.approx(0.030, rel=0.15)
    assert rep["heldout"]["shrink_pct"] >= 50


def test_dead_time_footprint_is_a_phase_line(dead_report):
    """Told apart from a lag: linear phase, no gain roll-off."""
    _, rep = dead_report
    fp = rep["evidence"]["signatures"]["effect_footprint"]
    assert fp["r2_linear_phase"] > 0.99 > fp["r2_atan_phase"]
    assert abs(fp["gain_error_at_top_dB"]) < 0.5
    assert fp["dead_time_equivalent_s"] == pytest.approx(0.030, rel=0.1)
    by = {r["effect"]: r for r in rep["ranking"]}
    assert by["dead_time"]["heldout_nrmse_pct"] < 0.2 * by["activation_dynamics"][
        "heldout_nrmse_pct"]


def test_cli_refuses_a_missing_file(tmp_path, capsys):
    from nmsid.cli import main
    assert main(["gap", str(tmp_path / "nope.h5"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.h5" in capsys.readouterr().err


def test_report_has_the_keys_and_files(dead_report):
    out, rep = dead_report
    for key in REQUIRED:
        assert key in rep
    for row in rep["ranking"]:
        assert {"effect", "params", "heldout_nrmse_pct", "delta_ic"} <= set(row)
    assert {"nominal_nrmse_pct", "augmented_nrmse_pct", "shrink_pct"} <= set(rep["heldout"])
    loc = rep["localization"]
    g = GapSettings()
    n_tested = len(loc["nominal"]["position"])
    assert 1 <= n_tested <= 15          # 5 sE x 3 repeats; the held-out ones are listed
    for model in ("nominal", "augmented"):
        assert [row["sE"] for row in loc[model]["sE"]] == [0.3, 0.5, 0.7, 0.9, 1.0]
        assert len(loc[model]["band"]) == len(g.bands_Hz) - 1
        assert len(loc[model]["deviation"]) == len(g.deviation_edges) - 1
        assert len(loc[model]["position"]) == n_tested
    # the named dead time removes most of the gap at every sE
    for nom, aug in zip(loc["nominal"]["sE"], loc["augmented"]["sE"], strict=True):
        assert aug["nrmse_pct"] < nom["nrmse_pct"], (nom, aug)
    for name in ("report.html", "twin.json", "where.png", "frequency.png"):
        assert (out / name).stat().st_size > 0


def test_twin_file_runs_in_the_simulator(dead_report):
    from nmsid.sim_backends import participant_from_twin
    out, _ = dead_report
    twin = json.loads((out / "twin.json").read_text())
    p = participant_from_twin(twin)
    assert p.effect_truth()[0]["name"] == "dead_time"
    assert p.effect_truth()[0]["params"]["L_s"] == pytest.approx(0.030, rel=0.15)


def test_nominal_session_is_none(nominal_session):
    diag = diagnose(load_session(nominal_session), GapSettings(try_pairs=False))
    assert diag.best is None
    assert diag.nominal.heldout_nrmse_pct < 2.0


def test_heldout_trials_never_fitted(nominal_session):
    """Changing a held-out trial's force changes no training fit of its fold."""
    data = load_session(nominal_session)
    diag = diagnose(data, GapSettings(candidates=(), try_pairs=False))
    fold = diag.folds[0]
    data2 = load_session(nominal_session)
    data2.y_N[fold.test] += np.random.default_rng(0).standard_normal(
        data2.y_N[fold.test].shape)
    diag2 = diagnose(data2, GapSettings(candidates=(), try_pairs=False))
    a, b = diag.nominal.fold_fits[0], diag2.nominal.fold_fits[0]
    np.testing.assert_array_equal(a.wn_rad_s, b.wn_rad_s)
    np.testing.assert_array_equal(a.Kp, b.Kp)
    assert diag2.nominal.heldout_nrmse_pct > diag.nominal.heldout_nrmse_pct


def test_effective_fraction_of_white_and_smooth_noise():
    rng = np.random.default_rng(1)
    white = rng.standard_normal((20, 1000))
    assert effective_fraction(white, 100.0, 25.0) == pytest.approx(0.5)  # bandwidth cap
    smooth = np.cumsum(rng.standard_normal((20, 1000)), axis=1)
    assert effective_fraction(smooth, 100.0, 25.0) < 0.05


def test_external_simulation_under_test(dead_report, dead_time_session, tmp_path):
    """--sim-session matches trials by sE and repeat; --twin runs the twin file with its
    effects: the augmented twin predicts the session, the same twin without its dead time
    does not."""
    from nmsid.analysis.gap.api import external_predictions
    out, _ = dead_report
    data = load_session(dead_time_session)
    same = external_predictions(data, sim_session=dead_time_session)
    np.testing.assert_allclose(same, data.y_N)

    X = np.column_stack([np.ones_like(data.t_eval_s), data.t_eval_s])

    def detrend(v):  # offset and linear trend, as the report does
        return v - (np.linalg.lstsq(X, v.T, rcond=None)[0].T @ X.T)

    def nrmse(pred):
        r, ref = detrend(data.y_N - pred), detrend(data.y_N)
        return 100 * np.sqrt(np.sum(r ** 2) / np.sum(ref ** 2))

    twin = json.loads((out / "twin.json").read_text())
    assert nrmse(external_predictions(data, twin=out / "twin.json")) < 1.0  # ~ noise
    twin["effects"] = []
    (tmp_path / "nominal_twin.json").write_text(json.dumps(twin))
    assert nrmse(external_predictions(data, twin=tmp_path / "nominal_twin.json")) > 10.0


def test_single_repeat_is_refused_with_a_clear_message(write_synthetic, tmp_path):
    from nmsid.analysis.gap.errors import GapInputError
    path = write_synthetic(tmp_path / "one.h5", levels=(0.3, 0.6), repeats=1)
    with pytest.raises(GapInputError, match="two repeats"):
        diagnose(load_session(path))


def test_pair_dead_time_and_fatigue(write_synthetic, tmp_path):
    """Two effects at once: the winner is one of them and the pair is found."""
    path = write_synthetic(tmp_path / "pair.h5", seed=5, dead_time_s=0.02, blocks=False,
                           fatigue_per_100s=0.12)
    diag = diagnose(load_session(path))
    assert diag.best_effect.value in ("dead_time", "fatigue")
    assert diag.best_pair is not None
    assert {e.value for e in diag.best_pair.candidate.effects} == {"dead_time", "fatigue"}
    assert diag.full_fit.params["L_s"] == pytest.approx(0.02, rel=0.15)
