"""identify_level / identify_session on synthetic sessions and on broken input."""

import numpy as np
import pytest

from nmsid.analysis.identify import identify_level, identify_session
from nmsid.protocols.session_file import Calibration, SessionWriter, Trial, read_session


def test_session_parameters_recovered(small_session):
    path, truth = small_session
    res = identify_session(path)
    assert res.participant == truth.participant and len(res.levels) == 6
    errs = []
    for lv in res.levels:
        kp, wn, zeta = truth.at(lv.sE)
        f = lv.fit
        assert f.converged and lv.n_trials == 2
        errs.append([f.Kp / kp - 1, f.wn_rad_s / wn - 1, f.zeta / zeta - 1])
        # the estimate lies within a few standard errors of the truth
        assert abs(f.Kp - kp) < 6 * f.Kp_se + 1e-4 * kp
        assert abs(f.wn_rad_s - wn) < 6 * f.wn_se + 1e-4 * wn
    assert np.max(np.abs(errs)) < 0.01
    assert res.problems == []
    row = res.levels[0].to_dict(res.participant)
    assert {"Kp", "wn_rad_s", "zeta", "fit_pct", "n_trials", "Kp_se"} <= set(row)


def _copy_trials(src, dst, edit):
    """Write a copy of a session with ``edit(trial)`` applied (None drops the trial)."""
    s = read_session(src)
    w = SessionWriter.create(dst, participant=s.participant)
    w.write_calibration(s.calibration)
    for tr in s.trials:
        tr = edit(tr)
        if tr is not None:
            w.append_trial(tr)
    return dst


def test_broken_session_gives_messages_and_goes_on(small_session, tmp_path):
    path, truth = small_session

    def edit(tr):
        if tr.sE == 0.3 and tr.repeat == 1:
            tr.status, tr.abort_reason = "aborted", "E-stop pressed"
            tr.force_N = tr.force_N[:4000]
            tr.rE, tr.I_ext_mA, tr.I_flex_mA = tr.rE[:4000], tr.I_ext_mA[:4000], tr.I_flex_mA[:4000]
        if tr.sE == 0.45 and tr.repeat == 2:
            tr.force_N = tr.force_N.copy()
            tr.force_N[12000:12010] = np.nan
        if tr.sE == 0.6 and tr.repeat == 2:
            return None                                   # missing trial
        if tr.sE == 0.75:
            tr.force_N = np.full(len(tr.force_N), np.nan)  # both repeats broken
        return tr

    broken = _copy_trials(path, tmp_path / "broken.h5", edit)
    res = identify_session(broken)
    text = "\n".join(res.problems)
    assert "aborted (E-stop pressed); skipped" in text
    assert "10 non-finite sample(s) in force_N" in text
    assert "sE=0.6: 1 of 2 repeats completed" in text
    assert "sE=0.75: no usable trial; level not identified" in text
    assert "only one usable repeat" in text
    by_sE = {round(lv.sE, 2): lv for lv in res.levels}
    assert by_sE[0.75].fit is None and np.isnan(by_sE[0.75].to_dict()["Kp"])
    for s in (0.3, 0.45, 0.6, 0.9, 1.0):
        kp = truth.at(s)[0]
        assert by_sE[s].fit is not None and abs(by_sE[s].fit.Kp / kp - 1) < 0.01


def test_identify_level_rejects_mixed_levels(small_session):
    s = read_session(small_session[0])
    with pytest.raises(ValueError, match="several sE"):
        identify_level(s.trials[:6])
    with pytest.raises(ValueError, match="at least one"):
        identify_level([])


def test_empty_session_reports(tmp_path):
    p = tmp_path / "empty.h5"
    w = SessionWriter.create(p, participant="P9")
    w.write_calibration(Calibration(1, 2, 1, 2))
    res = identify_session(p)
    assert res.levels == [] and "no trials" in res.problems[0]


def test_non_converging_fit_is_reported(small_session):
    from nmsid.analysis.settings import IdentificationSettings
    s = read_session(small_session[0])
    level = [t for t in s.trials if t.sE == 0.6]
    res = identify_level(level, IdentificationSettings(max_iterations=1))
    assert res.fit is not None and not res.fit.converged
    assert any("did not converge" in p for p in res.problems)


def test_too_few_levels_and_single_repeats_still_give_outputs(synthetic, tmp_path):
    from nmsid.analysis.run import run_identification
    path = tmp_path / "three.h5"
    synthetic.write_synthetic_session(path, seed=3, sE_levels=(0.3, 0.6, 0.9), repeats=1)
    out = run_identification([path], tmp_path / "out", figures=False)
    text = "\n".join(out.problems)
    assert "only one usable repeat" in text
    assert "no model is selectable" in text and "twin not written" in text
    assert (tmp_path / "out" / "parameters.csv").exists()
    assert not (tmp_path / "out" / "twin.json").exists()
    assert all(lv.fit is not None for lv in out.sessions[0].levels)


def test_planned_levels_and_repeats_from_the_stored_protocol(small_session, tmp_path):
    import json
    src = read_session(small_session[0])
    p = tmp_path / "planned.h5"
    cfg = {"protocol": {"sE_levels": [0.3, 0.45, 0.5], "repeats": 3}}
    w = SessionWriter.create(p, participant="P5", config_json=json.dumps(cfg))
    w.write_calibration(Calibration(1, 2, 1, 2))
    for tr in src.trials:
        if tr.sE in (0.3, 0.45):
            w.append_trial(tr)
    res = identify_session(p)
    text = "\n".join(res.problems)
    assert "sE=0.5: planned but no trial in the file" in text
    assert "sE=0.3: 2 of 3 repeats completed" in text


@pytest.mark.parametrize("params", [(14.0, 55.0, 0.22), (3.0, 9.0, 1.15)])
def test_noise_free_chirp_through_the_whole_pipeline(synthetic, params):
    """Paper protocol, drift and offset, no noise: detrend + filters + decimation + fit
    recover the parameters to a few 1e-6."""
    fs, n = 2000.0, 30000
    rE, y = synthetic.exact_response(*params, fs, n, 5.0, 10.0, 1.0, 10.0)
    t = np.arange(n) / fs
    trials = [Trial(sE=0.5, repeat=k + 1, fs_Hz=fs, rE=rE, I_ext_mA=rE, I_flex_mA=rE,
                    force_N=y + 0.5 * k - 0.3 + 0.02 * (k - 1) * t, name=f"t00{k + 1}")
              for k in range(3)]
    f = identify_level(trials).fit
    assert (f.Kp, f.wn_rad_s, f.zeta) == pytest.approx(params, rel=5e-6)
