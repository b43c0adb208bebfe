"""Tests that bite (issue 29, 5) for the STG download: the charge balance is checked on
what is sent, before anything is sent; the rendered ceiling is checked on both halves of
the carrier (a cathodic overshoot is as dangerous as an anodic one)."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.drivers import stg_download
from nmsid.drivers.errors import ChargeBalanceError
from nmsid.drivers.interfaces import CheckedWaveform, CurrentLimitError
from nmsid.drivers.stg_download import ChannelPlan, prepare_download
from nmsid.drivers.stg_waveform import RenderedChannel, check_rendered, compress

RATE, CARRIER, RES = 50_000.0, 1000.0, 500.0
P = int(RATE / CARRIER)                     # 50 output samples per carrier period
PLANS = (ChannelPlan(1, "extensor", 10.0, 16e6, RES), ChannelPlan(2, "flexor", 10.0, 16e6,
                                                                   RES))


def _waveform(n=200, mA=2.0):
    env = np.full(n, mA)
    return CheckedWaveform(env, env.copy(), 2000.0, CARRIER, 10.0, 10.0)


def _channel(pos_mA: float, neg_mA: float, periods: int = 5) -> RenderedChannel:
    """A square carrier: +pos for half a period, -neg for the other half, ending at 0."""
    half = P // 2
    one = np.r_[np.full(half, round(pos_mA * 1e6)), np.full(P - half, -round(neg_mA * 1e6))]
    samples = np.r_[np.tile(one, periods), 0].astype(np.int64)
    return compress(samples, int(1e6 / RATE), P)


def test_prepare_download_refuses_an_unbalanced_rendering(monkeypatch):
    # the renderer is balanced by construction; the check must still stand between a
    # rendering fault and the device
    monkeypatch.setattr(stg_download, "render_channel",
                        lambda *a, **kw: _channel(2.0, 1.0))
    with pytest.raises(ChargeBalanceError, match="net charge"):
        prepare_download(_waveform(), *PLANS, sync_out=1, output_rate_Hz=RATE)


def test_prepare_download_reports_the_worst_net_charge_of_each_channel():
    d = prepare_download(_waveform(), *PLANS, sync_out=1, output_rate_Hz=RATE)
    assert set(d.worst_net_nC) == {1, 2}
    assert all(0 <= v <= RES * 1e-6 / RATE * 1e6 for v in d.worst_net_nC.values())


def test_the_rendered_ceiling_is_checked_on_the_negative_half_too():
    check_rendered(_channel(9.0, 9.0), 10.0, "ok")                  # both halves inside
    with pytest.raises(CurrentLimitError, match="exceeds the ceiling"):
        check_rendered(_channel(9.0, 12.0), 10.0, "cathodic overshoot")
    with pytest.raises(CurrentLimitError, match="exceeds the ceiling"):
        check_rendered(_channel(12.0, 9.0), 10.0, "anodic overshoot")


def test_prepare_download_refuses_a_rendering_over_the_ceiling_on_either_half(monkeypatch):
    for pos, neg in ((11.0, 11.0), (5.0, 11.0)):
        monkeypatch.setattr(stg_download, "render_channel",
                            lambda *a, _p=pos, _n=neg, **kw: _channel(_p, _n))
        with pytest.raises(CurrentLimitError):
            prepare_download(_waveform(), *PLANS, sync_out=1, output_rate_Hz=RATE)


@pytest.mark.parametrize("rate, ok", [(999.0, False), (1000.0, True), (50_000.0, True),
                                      (50_001.0, False), (30_000.0, False),
                                      (40_000.0, True)])
def test_output_rates_are_the_vendors_whole_microsecond_ones(rate, ok):
    from nmsid.drivers.errors import StimulatorSettingError
    from nmsid.drivers.stg_download import check_output_rate
    if ok:
        assert check_output_rate(rate) == rate
    else:
        with pytest.raises(StimulatorSettingError):
            check_output_rate(rate)


@pytest.mark.parametrize("rate", [30_000.0, 3e6])   # 33.3 us; 0.33 us rounds to 0
def test_a_tick_that_is_not_a_whole_microsecond_is_refused(rate):
    from nmsid.drivers.errors import StimulatorSettingError
    from nmsid.drivers.stg_waveform import output_tick_us
    with pytest.raises(StimulatorSettingError):
        output_tick_us(rate)
    assert output_tick_us(50_000.0) == 20 and output_tick_us(1000.0) == 1000


def test_an_envelope_above_the_ceiling_is_refused_before_rendering(monkeypatch):
    def never(*a, **kw):
        raise AssertionError("rendered an envelope above the ceiling")

    monkeypatch.setattr(stg_download, "render_channel", never)
    small = (ChannelPlan(1, "extensor", 10.0, 2e6, RES), ChannelPlan(2, "flexor", 10.0, 2e6,
                                                                     RES))  # a 2 mA range
    with pytest.raises(CurrentLimitError, match="envelope peak"):
        prepare_download(_waveform(mA=3.0), *small, sync_out=1, output_rate_Hz=RATE)


def test_device_memory_is_estimated_per_point():
    d = prepare_download(_waveform(), *PLANS, sync_out=1, output_rate_Hz=RATE)
    assert d.channel_bytes() == {ch: r.n_points * stg_download.BYTES_PER_POINT
                                 for ch, r in d.channels.items()}
    assert all(v > 0 for v in d.channel_bytes().values())


def test_a_trial_shorter_than_one_carrier_period_has_no_period_to_output():
    """Closed form: 2000 Hz envelope at a 50 kHz output rate is 25 output samples per
    envelope sample; a 50-sample carrier period needs two envelope samples."""
    from nmsid.drivers.stg_waveform import period_amplitudes_mA
    amp, n_out = period_amplitudes_mA([3.0], 2000.0, RATE, P)
    assert amp.shape == (0,) and n_out == 25
    amp, n_out = period_amplitudes_mA([3.0, 1.0], 2000.0, RATE, P)
    assert n_out == 50 and np.allclose(amp, [2.0])       # mean of the held envelope
    amp, n_out = period_amplitudes_mA([3.0, 1.0, 5.0, 5.0, 1.0], 2000.0, RATE, P)
    assert n_out == 125 and np.allclose(amp, [2.0, 5.0])  # the half period left is not output


def test_a_trial_shorter_than_one_period_renders_no_current_and_a_balanced_channel():
    from nmsid.drivers.stg_waveform import check_charge_balance, render_channel
    ch = render_channel([3.0], 2000.0, CARRIER, RATE, RES)
    assert not ch.expand().any()
    assert check_charge_balance(ch, RES, "extensor") == 0.0
    # a channel with no data at all carries no charge (not an error of the check itself)
    empty = RenderedChannel(np.zeros(0, np.int64), np.zeros(0, np.int64), 20, P)
    assert check_charge_balance(empty, RES, "flexor") == 0.0
