"""Non-chirp inputs: the multisine, the input kind setting and the optional trial attrs."""

import json
import math

import numpy as np
import pytest

from nmsid.protocols.config import ConfigError, InputKind, config_from_dict, load_config
from nmsid.protocols.session_file import (
    Calibration,
    SessionWriter,
    Trial,
    read_session,
    trial_input,
    validate_session,
)
from nmsid.protocols.waveforms import (
    chirp_phase_rad,
    excitation,
    input_attrs,
    multisine_frequencies_Hz,
    multisine_unit,
    rE_signal,
    trial_waveform,
)
from nmsid.rig.safety import check_waveform


def _cfg(**protocol):
    return config_from_dict({"protocol": protocol})


@pytest.mark.parametrize("f0, f1, T, n", [(1.0, 10.0, 10.0, 24), (0.5, 8.0, 4.0, 6),
                                          (2.0, 12.0, 6.0, 30), (1.0, 10.0, 2.0, 19)])
def test_multisine_tones_are_distinct_harmonics_in_the_band(f0, f1, T, n):
    f = multisine_frequencies_Hz(f0, f1, T, n)
    assert len(f) == n and len(set(np.round(f * T, 9))) == n
    assert np.allclose(f * T, np.round(f * T))          # periodic over T
    assert f.min() >= f0 - 1e-9 and f.max() <= f1 + 1e-9
    assert f[0] == pytest.approx(math.ceil(f0 * T - 1e-9) / T)


def test_too_many_tones_are_refused_with_the_setting_named():
    with pytest.raises(ValueError, match="tones do not fit"):
        multisine_frequencies_Hz(1.0, 2.0, 2.0, 5)
    with pytest.raises(ConfigError, match="protocol.multisine_tones") as exc:
        _cfg(input_kind="multisine", chirp_s=2.0, chirp_f0_Hz=1.0, chirp_f1_Hz=2.0,
             multisine_tones=5)
    assert "at most 3" in str(exc.value)
    with pytest.raises(ConfigError, match="protocol.input_kind"):
        _cfg(input_kind="square")


@pytest.mark.parametrize("amp, centre, T, tones", [(0.5, 0.5, 6.0, 20), (0.3, 0.5, 4.0, 8),
                                                   (0.2, 0.4, 10.0, 24)])
def test_multisine_rE_peaks_at_the_amplitude_and_has_only_its_tones(amp, centre, T, tones):
    c = _cfg(input_kind="multisine", chirp_s=T, steady_s=1.0, rE_amplitude=amp,
             rE_centre=centre, multisine_tones=tones, fs_Hz=1000.0)
    p = c.protocol
    rE = rE_signal(p)
    i0 = int(p.steady_s * p.fs_Hz)
    assert np.all(rE[:i0] == centre)
    dev = rE[i0:] - centre
    assert np.max(np.abs(dev)) <= amp + 1e-12
    assert np.max(np.abs(dev)) >= 0.99 * amp          # the peak is used, not wasted
    assert abs(dev[0]) < 0.02 * amp                    # no step out of the lead-in
    spec = np.abs(np.fft.rfft(dev)) / len(dev)         # exactly one period: no leakage
    freqs = np.fft.rfftfreq(len(dev), 1 / p.fs_Hz)
    tones_Hz = multisine_frequencies_Hz(p.chirp_f0_Hz, p.chirp_f1_Hz, T, tones)
    on = np.isin(np.round(freqs * T), np.round(tones_Hz * T))
    assert on.sum() == tones
    assert np.sum(spec[~on] ** 2) < 1e-12 * np.sum(spec[on] ** 2)
    assert np.std(spec[on]) < 1e-6 * np.mean(spec[on])   # flat amplitude spectrum


def test_multisine_phases_keep_the_crest_factor_low():
    f = multisine_frequencies_Hz(1.0, 10.0, 10.0, 24)
    t = np.linspace(0, 10, 20000, endpoint=False)
    x = multisine_unit(t, f, 10.0)
    crest = np.max(np.abs(x)) / np.sqrt(np.mean(x ** 2))
    rng = np.random.default_rng(0)
    y = np.sin(2 * np.pi * np.outer(t, f) + rng.uniform(0, 2 * np.pi, len(f))).sum(axis=1)
    assert crest < 2.2 < np.max(np.abs(y)) / np.sqrt(np.mean(y ** 2))


def test_chirp_kind_is_unchanged_closed_form():
    c = _cfg(chirp_s=3.0, steady_s=0.5, chirp_f0_Hz=2.0, chirp_f1_Hz=9.0, fs_Hz=500.0)
    assert c.protocol.input_kind is InputKind.CHIRP
    t = np.arange(1500) / 500.0
    assert np.allclose(excitation(c.protocol, t), np.sin(chirp_phase_rad(t, 2.0, 9.0, 3.0)))


@pytest.mark.parametrize("sE", [0.3, 0.65, 1.0])
def test_multisine_currents_pass_the_interlock_waveform_check(sE):
    cal = Calibration(2.0, 15.5, 1.0, 16.0, 0.5, 5.0)
    c = _cfg(input_kind="multisine", chirp_s=4.0, steady_s=2.0, multisine_tones=20)
    wf = trial_waveform(c.protocol, sE, cal)
    assert wf.I_ext_mA.max() <= cal.Iemax_mA + 1e-9 and wf.I_flex_mA.max() <= cal.Ifmax_mA + 1e-9
    checked = check_waveform(wf.I_ext_mA, wf.I_flex_mA, fs_Hz=wf.fs_Hz, carrier_Hz=1000.0,
                             ceiling_ext_mA=16.0, ceiling_flex_mA=16.0, device_max_mA=16.0)
    assert checked.n_samples == wf.n_samples


def test_input_kind_round_trips_through_toml_and_json(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('[protocol]\ninput_kind = "multisine"\nchirp_s = 6.0\nmultisine_tones = 12\n')
    c = load_config(path)
    assert c.protocol.input_kind is InputKind.MULTISINE and c.protocol.multisine_tones == 12
    d = json.loads(c.to_json())
    assert d["protocol"]["input_kind"] == "multisine"
    back = config_from_dict(d)
    assert back.protocol == c.protocol


def test_input_attrs_are_written_read_and_default_to_the_chirp(tmp_path):
    c = _cfg(input_kind="multisine", chirp_s=4.0, steady_s=1.0, multisine_tones=10,
             fs_Hz=500.0)
    p = c.protocol
    attrs = input_attrs(p)
    assert attrs["input_kind"] == "multisine"
    spec = json.loads(attrs["input_json"])
    assert len(spec["tones_Hz"]) == 10 and spec["duration_s"] == 4.0
    path = tmp_path / "s.h5"
    w = SessionWriter.create(path, participant="P01")
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0))
    rE = rE_signal(p)
    n = len(rE)
    for kind_attrs in (attrs, {}):
        w.append_trial(Trial(sE=0.5, repeat=1, fs_Hz=p.fs_Hz, rE=rE, I_ext_mA=rE,
                             I_flex_mA=rE, force_N=np.zeros(n), steady_s=1.0, chirp_s=4.0,
                             extra_attrs=dict(kind_attrs)))
    assert validate_session(path) == []
    t1, t2 = read_session(path).trials
    got = trial_input(t1)
    assert got["kind"] == "multisine" and got["tones_Hz"] == spec["tones_Hz"]
    plain = trial_input(t2)
    assert plain["kind"] == "chirp" and plain["duration_s"] == 4.0 and plain["f1_Hz"] == 10.0


def test_schroeder_phases_reduce_to_the_classic_formula_for_consecutive_harmonics():
    from nmsid.protocols.waveforms import schroeder_phases_rad
    K, T = 12, 2.0
    f = np.arange(1, K + 1) / T
    k = np.arange(1, K + 1)
    assert np.allclose(schroeder_phases_rad(f, T), -np.pi * k * (k - 1) / K)
