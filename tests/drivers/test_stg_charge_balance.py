"""Charge balance by construction: every carrier period of every channel nets zero charge.

Property tests over calibrations, sE, input kinds (chirp, multisine), output rates and
carrier frequencies, on the rendered, quantised samples the driver would download
(``drivers.stg_download.prepare_download``, the driver's own code path), checked by an
independent period-by-period sum here; and the check's refusal of unbalanced data.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers.errors import ChargeBalanceError, StimulatorSettingError
from nmsid.drivers.interfaces import CheckedWaveform
from nmsid.drivers.stg_download import ChannelPlan, prepare_download
from nmsid.drivers.stg_waveform import (
    RenderedChannel,
    check_charge_balance,
    compress,
    render_channel,
    samples_per_period,
)
from nmsid.protocols.config import config_from_dict
from nmsid.protocols.waveforms import trial_waveform


class Cal:
    def __init__(self, Iemin, Iemax, Ifmin, Ifmax):
        self.Iemin_mA, self.Iemax_mA, self.Ifmin_mA, self.Ifmax_mA = Iemin, Iemax, Ifmin, Ifmax


def protocol(kind: str, fs: float, carrier: float):
    return config_from_dict({"protocol": {
        "input_kind": kind, "steady_s": 0.05, "chirp_s": 0.25, "fs_Hz": fs,
        "carrier_Hz": carrier, "chirp_f0_Hz": 4.0, "chirp_f1_Hz": 200.0,
        "multisine_tones": 4}}).protocol


# output rates the STG accepts (1..50 kHz, whole us per sample) and carriers that are a
# whole number of samples per period at that rate
RATES = [50_000.0, 40_000.0, 25_000.0, 20_000.0, 10_000.0]


@st.composite
def rate_and_carrier(draw):
    rate = draw(st.sampled_from(RATES))
    P = draw(st.integers(4, 100))
    return rate, rate / P


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(["chirp", "multisine"]), rc=rate_and_carrier(),
       sE=st.floats(0.05, 1.0), Iemin=st.floats(0.0, 6.0), de=st.floats(0.5, 10.0),
       Ifmin=st.floats(0.0, 6.0), df=st.floats(0.5, 10.0),
       res=st.sampled_from([100.0, 244.140625, 500.0, 1000.0]),
       fs=st.sampled_from([1000.0, 1200.0, 2000.0]))
def test_every_carrier_period_nets_zero_charge(kind, rc, sE, Iemin, de, Ifmin, df, res, fs):
    rate, carrier = rc
    p = protocol(kind, fs, carrier)
    wf = trial_waveform(p, sE, Cal(Iemin, Iemin + de, Ifmin, Ifmin + df))
    checked = CheckedWaveform(wf.I_ext_mA, wf.I_flex_mA, fs, carrier, 16.0, 16.0)
    plans = [ChannelPlan(1, "extensor", 16.0, 16e6, res), ChannelPlan(2, "flexor", 16.0,
                                                                       16e6, res)]
    dl = prepare_download(checked, *plans, sync_out=1, output_rate_Hz=rate)
    P = int(round(rate / carrier))
    for ch, env in ((1, wf.I_ext_mA), (2, wf.I_flex_mA)):
        x = dl.channels[ch].expand()
        assert x[-1] == 0 and np.abs(x).max() <= env.max() * 1e6 + 1e-6
        n = (len(x) - 1) // P
        sums = x[:n * P].reshape(n, P).sum(axis=1)
        assert np.all(sums == 0)                      # independent of the driver's check
        assert np.all(x[n * P:] == 0)                 # no partial period is played
        assert dl.worst_net_nC[ch] == 0.0
        if env.max() > 1.0 and P >= 6:                # the carrier really is there
            assert np.abs(x).max() >= 0.5 * env.min() * 1e6


def test_unbalanced_data_is_refused_naming_the_period():
    period = np.array([0, 1000, 0, -500], dtype=np.int64)       # +500 nA x tick net
    ch = compress(np.tile(period, 3), 20, period_ticks=4)
    with pytest.raises(ChargeBalanceError, match=r"extensor: carrier period 0 carries a net "
                                                 r"charge of 0\.010 nC"):
        check_charge_balance(ch, 100.0, "extensor")
    # within one resolution step is accepted (the device cannot do better)
    assert check_charge_balance(ch, 500.0, "extensor") == pytest.approx(0.01)


def test_carrier_not_a_whole_number_of_samples_is_refused():
    with pytest.raises(StimulatorSettingError, match="carrier 3000 Hz is not a whole number"):
        samples_per_period(50_000.0, 3000.0)
    with pytest.raises(StimulatorSettingError, match="4, 5, 6"):
        render_channel(np.ones(10), 2000.0, 25_000.0, 50_000.0, 500.0)


def test_old_renderer_would_be_refused_by_the_check():
    # the previous renderer held the 2 kHz envelope for half a carrier period
    env = np.repeat([2.0, 16.0], 1000)
    j = np.arange(50_000)
    k = np.minimum((j * 2000 / 50_000 + 1e-9).astype(int), len(env) - 1)
    old = np.trunc(env[k] * 1e6 * np.sin(2 * np.pi * 1000 * j / 50_000) / 500) * 500
    env_alt = np.tile([2.0, 16.0], 1000)                         # alternating samples
    k2 = np.minimum((j * 2000 / 50_000 + 1e-9).astype(int), len(env_alt) - 1)
    old2 = np.trunc(env_alt[k2] * 1e6 * np.sin(2 * np.pi * 1000 * j / 50_000) / 500) * 500
    for samples in (old, old2):
        ch = RenderedChannel(*_compress_arrays(samples), 20, 50)
        if np.any(samples.reshape(-1, 50).sum(axis=1) != 0):
            with pytest.raises(ChargeBalanceError):
                check_charge_balance(ch, 500.0, "old")
    assert np.abs(old2.reshape(-1, 50).sum(axis=1)).max() * 20e-6 > 50  # > 50 nC


def _compress_arrays(samples):
    c = compress(samples.astype(np.int64), 20, 50)
    return c.values_nA, c.durations_us
