"""The STG download's save-stop marks, rate bounds and memory figures, against closed forms.

McsUsbNet 5.3.15 (XML, ``SendStop`` with ``STOP_OPTION_SAVESTOP``): the save stop "bypasses
the stop commands when a syncout ... has bit 1 (0x02) set", so bit 1 must be set on every
tick of a carrier period that carries current except the period's first (0 nA) tick, and
nowhere else; bit 0 is the trial's sync level throughout.
"""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.drivers.stg_download import (
    BYTES_PER_POINT,
    SYNC_HIGH,
    SYNC_SAVE_STOP,
    check_output_rate,
    save_stop_marks,
)
from nmsid.drivers.stg_waveform import RenderedChannel


def _channel(samples, period_ticks, tick_us=20):
    samples = np.asarray(samples, dtype=np.int64)
    return RenderedChannel(samples, np.full(len(samples), tick_us, dtype=np.int64), tick_us,
                           period_ticks)


def test_save_stop_bit_marks_active_periods_but_their_first_tick():
    P = 4
    # period 0 carries current, period 1 is silent, period 2 carries current (cut short)
    ch = _channel([0, 5, -5, 0, 0, 0, 0, 0, 0, 7, -7], P)
    out = save_stop_marks([ch], 11)
    expected = np.full(11, SYNC_HIGH)
    for k in (1, 2, 3, 9, 10):
        expected[k] |= SYNC_SAVE_STOP
    assert out.tolist() == expected.tolist()


def test_either_channel_marks_a_period_and_sync_data_marks_none():
    P = 2
    ext = _channel([0, 3, 0, 0], P)
    flex = _channel([0, 0, 0, 4], P)
    sync_like = _channel([1, 1, 1, 1], 0)     # period 0: sync data, never marks
    out = save_stop_marks([sync_like, ext, flex], 4)
    assert out.tolist() == [SYNC_HIGH, SYNC_HIGH | SYNC_SAVE_STOP,
                            SYNC_HIGH, SYNC_HIGH | SYNC_SAVE_STOP]


@pytest.mark.parametrize("rate", [999.0, 50_001.0, 0.0, -1000.0])
def test_an_output_rate_outside_the_documented_range_is_refused(rate):
    with pytest.raises(Exception, match="1000 .. 50000 Hz"):
        check_output_rate(rate)


def test_the_documented_rates_are_taken():
    assert check_output_rate(50_000.0) == 50_000.0
    assert check_output_rate(1000.0) == 1000.0


def test_memory_figures_count_the_download_points():
    from nmsid.drivers.interfaces import CheckedWaveform  # noqa: PLC0415
    from nmsid.drivers.stg_download import (  # noqa: PLC0415
        STG4002_RANGE_NA,
        STG4002_RESOLUTION_NA,
        ChannelPlan,
        prepare_download,
    )
    env = np.full(200, 2.0)
    dl = prepare_download(CheckedWaveform(env, env, 2000.0, 1000.0, 5.0, 5.0),
                          ChannelPlan(1, "extensor", 5.0, STG4002_RANGE_NA,
                                      STG4002_RESOLUTION_NA),
                          ChannelPlan(2, "flexor", 5.0, STG4002_RANGE_NA,
                                      STG4002_RESOLUTION_NA), 0, 50_000.0)
    assert dl.sync_bytes == dl.sync.n_points * BYTES_PER_POINT > 0
    assert dl.channel_bytes() == {ch: r.n_points * BYTES_PER_POINT
                                  for ch, r in dl.channels.items()}


@pytest.mark.parametrize("rate", [30_000.0, 3000.0, 49_999.0])
def test_a_rate_inside_the_range_but_not_a_whole_microsecond_tick_is_refused(rate):
    from nmsid.drivers.errors import StimulatorSettingError  # noqa: PLC0415
    with pytest.raises(StimulatorSettingError, match="whole number of microseconds"):
        check_output_rate(rate)


def test_a_waveform_whose_ceiling_exceeds_the_rigs_is_refused_even_with_a_small_envelope():
    """The waveform was checked against a ceiling the rig does not allow: refused as such,
    whatever its envelope (McsUsbNet is never asked)."""
    from nmsid.drivers.errors import DeviceRangeError  # noqa: PLC0415
    from nmsid.drivers.interfaces import CheckedWaveform  # noqa: PLC0415
    from nmsid.drivers.stg_download import ChannelPlan, prepare_download  # noqa: PLC0415
    env = np.full(200, 2.0)
    plans = (ChannelPlan(1, "extensor", 10.0, 16e6, 500.0),
             ChannelPlan(2, "flexor", 10.0, 16e6, 500.0))
    for ceilings in ((12.0, 10.0), (10.0, 12.0)):
        wf = CheckedWaveform(env, env.copy(), 2000.0, 1000.0, *ceilings)
        with pytest.raises(DeviceRangeError, match="exceeds the rig ceiling 10 mA"):
            prepare_download(wf, *plans, sync_out=1, output_rate_Hz=50_000.0)


def test_an_envelope_exactly_at_the_ceiling_is_sent():
    """The ceiling is the highest current allowed, not the first one refused."""
    from nmsid.drivers.interfaces import CheckedWaveform  # noqa: PLC0415
    from nmsid.drivers.stg_download import ChannelPlan, prepare_download  # noqa: PLC0415
    env = np.r_[np.full(100, 10.0), np.zeros(100)]
    plans = (ChannelPlan(1, "extensor", 10.0, 16e6, 500.0),
             ChannelPlan(2, "flexor", 10.0, 16e6, 500.0))
    wf = CheckedWaveform(env, env.copy(), 2000.0, 1000.0, 10.0, 10.0)
    prepare_download(wf, *plans, sync_out=1, output_rate_Hz=50_000.0)
