"""Waveforms against closed-form answers: the chirp's phase and frequency, eqs. (1)-(4)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.protocols.config import ProtocolConfig
from nmsid.protocols.session_file import Calibration
from nmsid.protocols.waveforms import (
    chirp_frequency_Hz,
    chirp_phase_rad,
    currents_mA,
    rE_signal,
    trial_waveform,
)


def test_chirp_frequency_is_the_phase_derivative():
    f0, f1, T = 1.0, 10.0, 10.0
    t = np.linspace(0, T, 200001)
    phi = chirp_phase_rad(t, f0, f1, T)
    f_num = np.gradient(phi, t) / (2 * np.pi)
    f = chirp_frequency_Hz(t, f0, f1, T)
    assert np.max(np.abs(f_num[1:-1] - f[1:-1])) < 1e-4
    assert f[0] == pytest.approx(1.0) and f[-1] == pytest.approx(10.0)
    assert chirp_frequency_Hz(5.0, f0, f1, T) == pytest.approx(np.sqrt(10))  # geometric mean
    # closed form: total phase = 2 pi f0 T (k - 1) / ln k
    assert phi[-1] == pytest.approx(2 * np.pi * 1 * 10 * 9 / np.log(10))


def test_time_at_frequency_inverts_frequency():
    # the exponential chirp's time at frequency f: T ln(f / f0) / ln(f1 / f0)
    t = np.linspace(0, 10, 11)
    f = chirp_frequency_Hz(t, 1, 10, 10)
    assert np.allclose(10 * np.log(f / 1) / np.log(10 / 1), t)


def normalised_from_currents(I_ext_mA, I_flex_mA, Iemin_mA, Iemax_mA, Ifmin_mA, Ifmax_mA):
    """The paper's equations (1)-(4) forward, the oracle of ``currents_mA``: (Ie, If, rE,
    sE) from the applied currents."""
    Ie = (np.asarray(I_ext_mA, dtype=float) - Iemin_mA) / (Iemax_mA - Iemin_mA)
    If = (np.asarray(I_flex_mA, dtype=float) - Ifmin_mA) / (Ifmax_mA - Ifmin_mA)
    sE = Ie + If
    with np.errstate(invalid="ignore", divide="ignore"):
        rE = np.where(sE != 0, Ie / np.where(sE != 0, sE, 1.0), np.nan)
    return Ie, If, rE, sE


def test_rE_is_steady_then_chirp():
    p = ProtocolConfig()
    rE = rE_signal(p)
    assert len(rE) == 30000
    assert np.all(rE[:10000] == 0.5)
    assert rE.min() >= 0 and rE.max() <= 1
    k = np.arange(10000, 30000)
    tc = (k / 2000.0) - 5.0
    phase = 2 * np.pi * 10 / np.log(10) * (10 ** (tc / 10) - 1)
    assert np.allclose(rE[k], 0.5 + 0.5 * np.sin(phase))
    assert rE.max() > 0.999 and rE.min() < 0.001


@given(sE=st.floats(0.01, 1.0), rE=st.floats(0, 1),
       Iemin=st.floats(0, 10), de=st.floats(0.1, 20), Ifmin=st.floats(0, 10),
       df=st.floats(0.1, 20))
@settings(max_examples=200, deadline=None)
def test_currents_invert_equations_1_to_4(sE, rE, Iemin, de, Ifmin, df):
    Ie, If = currents_mA(np.array([rE]), sE, Iemin, Iemin + de, Ifmin, Ifmin + df)
    ne, nf, r, s = normalised_from_currents(Ie, If, Iemin, Iemin + de, Ifmin, Ifmin + df)
    assert s[0] == pytest.approx(sE, abs=1e-9)
    assert r[0] == pytest.approx(rE, abs=1e-7)
    assert ne[0] == pytest.approx(rE * sE, abs=1e-9) and nf[0] == pytest.approx((1 - rE) * sE,
                                                                               abs=1e-9)
    # never above Imax (the calibration bounds the currents)
    assert Ie[0] <= Iemin + de + 1e-9 and If[0] <= Ifmin + df + 1e-9


def test_trial_waveform_hand_values():
    cal = Calibration(2.0, 10.0, 1.0, 5.0)
    wf = trial_waveform(ProtocolConfig(), 0.5, cal)
    # rE = 0.5, sE = 0.5: Ie = If = 0.25 -> 2 + 0.25*8 = 4 mA, 1 + 0.25*4 = 2 mA
    assert wf.I_ext_mA[0] == pytest.approx(4.0) and wf.I_flex_mA[0] == pytest.approx(2.0)
    with pytest.raises(ValueError):
        trial_waveform(ProtocolConfig(), 1.2, cal)
