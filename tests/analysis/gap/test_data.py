"""Session -> arrays: aborted and NaN trials are skipped but count for stimulation time."""

import numpy as np
import pytest

from nmsid.analysis.gap.data import load_session, prepare_trials
from nmsid.analysis.gap.errors import GapInputError
from nmsid.protocols.session_file import Trial, read_session


def test_aborted_and_nan_trials_are_skipped_and_reported(nominal_session):
    trials = read_session(nominal_session).trials
    n = trials[0].n_samples
    aborted = Trial(sE=0.5, repeat=4, fs_Hz=2000.0, rE=np.full(n // 3, 0.5),
                    I_ext_mA=np.zeros(n // 3), I_flex_mA=np.zeros(n // 3),
                    force_N=np.zeros(n // 3), status="aborted", abort_reason="E-stop",
                    name="t002")
    broken = Trial(**{**trials[1].__dict__, "force_N": np.full(n, np.nan), "name": "t003"})
    data = prepare_trials([trials[0], aborted, broken] + trials[2:])
    assert data.n_trials == len(trials) - 1
    assert any("aborted" in s and "E-stop" in s for s in data.skipped)
    assert any("NaN" in s for s in data.skipped)
    # the aborted trial stimulated: cumulative stimulation after it includes its length
    full = load_session(nominal_session)
    shift = (n // 3 + n) / 2000.0
    np.testing.assert_allclose(data.cum_stim_s[1:], full.cum_stim_s[2:] + shift - n / 2000.0,
                               atol=1e-9)


def test_window_and_rates(nominal_session):
    data = load_session(nominal_session)
    # one signal path: the models run at the identification's fit rate
    assert data.fs_sim_Hz == 200.0 and data.fs_eval_Hz == 100.0
    # 10 s chirp minus the 0.3 s end margin
    assert 9.68 <= data.t_eval_s[-1] + 1 / data.fs_eval_Hz <= 9.7 + 1e-9
    assert data.f_inst_Hz[0] == pytest.approx(1.0) and data.f_inst_Hz[-1] < 10.0
    assert np.all(np.isfinite(data.steady_noise_N2))


def test_no_usable_trial_is_refused(nominal_session):
    trials = read_session(nominal_session).trials[:2]
    for t in trials:
        t.status, t.abort_reason = "aborted", "test"
    with pytest.raises(GapInputError, match="no completed trial"):
        prepare_trials(trials, path="x.h5")
