"""Preprocessing: the paper's steps, exact on signals with known answers."""

import numpy as np
import pytest

from nmsid.analysis.errors import IdentificationError, SettingError
from nmsid.analysis.preprocess import (linear_detrend, preprocess_trials, smooth_and_lowpass,
                                       window_indices)
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
