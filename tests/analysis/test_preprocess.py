"""Preprocessing: the paper's steps, exact on signals with known answers."""

import dataclasses

import numpy as np
import pytest

from nmsid.analysis.errors import IdentificationError, SettingError
from nmsid.analysis.preprocess import (
    linear_detrend,
    preprocess_trials,
    smooth_and_lowpass,
    window_indices,
)
from nmsid.analysis.settings import IdentificationSettings
from nmsid.protocols.session_file import Trial

FS = 2000.0


def trial(force, rE=None, name="t001", sE=0.5, repeat=1, **kw):
    n = len(force)
    rE = np.full(n, 0.5) if rE is None else rE
    return Trial(sE=sE, repeat=repeat, fs_Hz=FS, rE=rE, I_ext_mA=rE, I_flex_mA=rE,
                 force_N=np.asarray(force, float), name=name, **kw)


def test_linear_detrend_matches_scipy():
    from scipy.signal import detrend
    x = np.random.default_rng(0).standard_normal(3001) + 0.01 * np.arange(3001)
    assert np.allclose(linear_detrend(x), detrend(x, type="linear"), atol=1e-10)


def test_linear_detrend_from_a_start_is_the_tail_of_the_whole():
    """The cache detrends only what its filters see: the same numbers, bit for bit."""
    x = np.random.default_rng(5).standard_normal(3001).cumsum() + 0.01 * np.arange(3001)
    whole = linear_detrend(x)
    for start in (0, 1, 900, 3000):
        assert np.array_equal(linear_detrend(x, start), whole[start:])
    assert np.array_equal(linear_detrend(np.array([2.0]), 0), np.array([0.0]))


def test_filters_pass_lines_and_kill_mains():
    t = np.arange(20000) / FS
    s = IdentificationSettings()
    line = 1.0 - 0.3 * t
    assert np.allclose(smooth_and_lowpass(line, FS, s), line, atol=1e-9)
    mains = np.sin(2 * np.pi * 50 * t)
    out = smooth_and_lowpass(mains, FS, s)[2000:-2000]
    assert np.max(np.abs(out)) < 1 / 250                  # order-4 filtfilt: 1/257 at 50 Hz
    slow = np.sin(2 * np.pi * 10 * t)
    assert np.max(np.abs(smooth_and_lowpass(slow, FS, s) - slow)[2000:-2000]) < 2e-3


def test_causal_filter_delays_and_zero_phase_does_not():
    t = np.arange(20000) / FS
    x = np.sin(2 * np.pi * 5 * t)
    zp = smooth_and_lowpass(x, FS, IdentificationSettings(savgol_window=None))
    ca = smooth_and_lowpass(x, FS, IdentificationSettings(savgol_window=None, zero_phase=False))
    lag = lambda y: np.argmax(np.correlate(y[4000:8000], x[4000:8000], "full")) - 3999  # noqa
    assert lag(zp) == 0
    assert 15 <= lag(ca) <= 40                            # 7.5-20 ms at 2000 Hz


def test_average_window_and_decimation():
    n = 30000
    t = np.arange(n) / FS
    rE = np.where(t < 5, 0.5, 0.5 + 0.5 * np.sin(2 * np.pi * 2 * (t - 5)))
    f1 = 2.0 * (rE - 0.5) + 0.3 + 0.01 * t
    f2 = 2.0 * (rE - 0.5) - 0.2
    d = preprocess_trials([trial(f1, rE), trial(f2, rE, name="t002", repeat=2)])
    assert d.n_trials == 2 and d.fs_Hz == 200.0
    assert d.t_s[0] == pytest.approx(5.0)
    trim = IdentificationSettings().edge_trim_samples(FS) / FS
    assert d.t_s[-1] <= 15.0 - trim
    assert abs(np.mean(d.u)) < 1e-12
    assert d.baseline_N == pytest.approx(np.mean([0.3 + 0.01 * 3.75, -0.2]), abs=1e-3)


def test_trials_of_different_length_use_common_part():
    n = 30000
    f = np.zeros(n)
    d = preprocess_trials([trial(f), trial(f[:25000], name="t002")])
    assert d.t_s[-1] < 12.5


def test_errors():
    with pytest.raises(IdentificationError, match="no trials"):
        preprocess_trials([])
    with pytest.raises(IdentificationError, match="too short"):
        preprocess_trials([trial(np.zeros(10500))])
    a = trial(np.zeros(30000))
    b = trial(np.zeros(30000), name="t002")
    b.fs_Hz = 1000.0
    with pytest.raises(IdentificationError, match="different rates"):
        preprocess_trials([a, b])
    with pytest.raises(IdentificationError, match="Nyquist"):
        preprocess_trials([trial(np.zeros(30000))],
                          IdentificationSettings(lowpass_Hz=1500.0, fit_fs_Hz=None))


def test_settings_are_validated_with_named_values():
    with pytest.raises(SettingError, match="savgol_window = 40"):
        IdentificationSettings(savgol_window=40)
    with pytest.raises(SettingError, match="fit_fs_Hz = 50"):
        IdentificationSettings(fit_fs_Hz=50.0)
    with pytest.raises(SettingError, match="input_hold"):
        IdentificationSettings(input_hold="cubic")
    s = IdentificationSettings(input_hold="linear")
    assert s.as_dict()["input_hold"] == "linear"
    assert window_indices(30000, FS, 5.0, 10.0, s) == (10000, 30000)


def test_no_lead_in_and_other_rates_still_recover_the_model(synthetic):
    """A trial without lead-in (the window starts at the first sample) at 1000 Hz."""
    from nmsid.analysis.second_order import fit_second_order
    fs = 1000.0
    rE, y = synthetic.exact_response(6.0, 25.0, 0.5, fs, 8000, 0.0, 8.0, 1.0, 10.0)
    tr = Trial(sE=0.5, repeat=1, fs_Hz=fs, rE=rE, I_ext_mA=rE, I_flex_mA=rE,
               force_N=y + 0.4, name="t001", steady_s=0.0, chirp_s=8.0)
    d = preprocess_trials([tr])
    assert d.t_s[0] > 0.1 and d.fs_Hz == 200.0
    f = fit_second_order(d.u, d.y_N, d.fs_Hz)
    assert (f.Kp, f.wn_rad_s, f.zeta) == pytest.approx((6.0, 25.0, 0.5), rel=2e-5)


def _chirp_trials(n_trials=3, n=30000, seed=4):
    """Repeats receiving one chirp rE, each with its own noisy force (a linear response)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    tc = np.clip(t - 5.0, 0.0, None)
    rE = np.where(t < 5, 0.5, 0.5 + 0.5 * np.sin(2 * np.pi * (1.0 + 0.45 * tc) * tc))
    out = []
    for k in range(n_trials):
        force = (1.5 + 0.1 * k) * (rE - 0.5) + 0.2 * k + 0.01 * t \
            + 0.02 * rng.standard_normal(n)
        out.append(trial(force, rE.copy(), name=f"t{k + 1:03d}", repeat=k + 1))
    return out


def _counting(monkeypatch):
    """Count the rows smooth_and_lowpass filters (the cache's work)."""
    import nmsid.analysis.preprocess as pre
    rows = []
    real = pre.smooth_and_lowpass

    def counted(x, fs_Hz, settings):
        rows.append(np.atleast_2d(x).shape[0])
        return real(x, fs_Hz, settings)

    monkeypatch.setattr(pre, "smooth_and_lowpass", counted)
    return rows


def test_trial_signals_give_the_result_of_filtering_the_average(monkeypatch):
    """Filtering each repeat once and averaging equals filtering the average (linear
    steps), for the level with and without a delay and for each repeat alone; the force
    is filtered once per repeat and the shared rE once per delay."""
    from nmsid.analysis.preprocess import TrialSignals
    s = IdentificationSettings()
    trials = _chirp_trials()
    plain = {(d, k): preprocess_trials(trials if k is None else [trials[k]], s,
                                       input_delay_s=d)
             for d in (0.0, 2.5e-4) for k in (None, 0, 1, 2)}
    rows = _counting(monkeypatch)
    cache = TrialSignals(s)
    for (d, k), ref in plain.items():
        got = preprocess_trials(trials if k is None else [trials[k]], s, input_delay_s=d,
                                cache=cache)
        scale = np.max(np.abs(ref.y_N))
        assert np.allclose(got.y_N, ref.y_N, rtol=0, atol=1e-12 * scale)
        assert np.allclose(got.u, ref.u, rtol=0, atol=1e-12)
        assert np.array_equal(got.t_s, ref.t_s)
        assert (got.fs_Hz, got.n_trials, got.input_delay_s, got.baseline_N) == \
            (ref.fs_Hz, ref.n_trials, ref.input_delay_s, ref.baseline_N)
        assert got.rE_mean == pytest.approx(ref.rE_mean, abs=1e-12)
    # 3 forces + the one rE at delay 0, then the rE at 0.25 ms; nothing for single repeats
    assert rows == [4, 1]


def test_trial_signals_filter_different_inputs_apart(monkeypatch):
    from nmsid.analysis.preprocess import TrialSignals
    s = IdentificationSettings()
    trials = _chirp_trials()
    trials[2].rE[12000] += 1e-3          # one sample differs: its own rE row
    ref = preprocess_trials(trials, s)
    rows = _counting(monkeypatch)
    got = preprocess_trials(trials, s, cache=TrialSignals(s))
    assert rows == [5]
    assert np.allclose(got.u, ref.u, rtol=0, atol=1e-12)


def test_trial_signals_step_aside_where_averaging_first_differs(monkeypatch):
    """Repeats of different lengths (cut to the common part), other settings and a
    settings object other than the cache's are filtered as before: the same numbers."""
    from nmsid.analysis.preprocess import TrialSignals
    s = IdentificationSettings()
    trials = _chirp_trials()
    short = dataclasses.replace(trials[1], force_N=trials[1].force_N[:25000],
                                rE=trials[1].rE[:25000])
    cache = TrialSignals(s)
    for group, settings in (([trials[0], short], s),
                            (trials, IdentificationSettings()),
                            (trials, IdentificationSettings(prefilter_input=False))):
        assert not cache.applies(group, settings)
        ref = preprocess_trials(group, settings)
        rows = _counting(monkeypatch)
        got = preprocess_trials(group, settings, cache=cache)
        assert np.array_equal(got.y_N, ref.y_N) and np.array_equal(got.u, ref.u)
        assert rows and rows[0] <= 2               # the average, not each repeat
