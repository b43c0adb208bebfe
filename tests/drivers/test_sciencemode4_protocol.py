"""The ScienceMode4 codec against the worked packets of the RehaMove3 description (RM3 7)
and the refusals that the ``science_mode_4`` package lacks (issue 43)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers import sciencemode4_protocol as p
from nmsid.drivers.errors import ProtocolError


def _hex(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


# RM3 7.1 and 7.2, verbatim
WORKED = [
    (p.encode(0, p.LL_INIT, p.ll_init_data()), "F0 81 55 81 58 81 55 81 55 00 00 00 0F"),
    (p.encode(1, p.LL_CHANNEL_CONFIG,
              p.ll_channel_config_data(0, 0, [(250, 20), (100, 0), (250, -20)])),
     "F0 81 55 81 4E 81 D3 81 AF 04 02 82 81 5A A5 50 00 06 44 B0 00 81 5A A4 10 00 0F"),
    (p.encode(2, p.LL_STOP), "F0 81 55 81 59 81 9C 81 78 08 04 0F"),
    (p.encode(0, p.ML_INIT, bytes((0,))), "F0 81 55 81 58 81 75 81 29 00 1E 00 0F"),
    (p.encode(1, p.ML_UPDATE, p.ml_update_data(
        {0: (20, [(200, 20), (100, 0), (200, -20)]),
         1: (10, [(100, 10), (100, 0), (100, -10)])}, ramp=3)),
     "F0 81 55 81 7E 81 5D 81 42 04 20 03 23 00 50 0C 85 50 00 06 44 B0 00 0C 84 10 00 23 "
     "00 28 06 45 00 00 06 44 B0 00 06 44 60 00 0F"),
    (p.encode(2, p.ML_GET_CURRENT_DATA, p.ml_get_current_data_data()),
     "F0 81 55 81 58 81 16 81 94 08 24 02 0F"),
    (p.encode(3, p.ML_STOP), "F0 81 55 81 59 81 14 81 18 0C 22 0F"),
]


@pytest.mark.parametrize("built,expected", WORKED)
def test_every_worked_packet_of_the_description(built, expected):
    assert built == _hex(expected)


def test_decoder_reads_each_worked_packet_back_even_split():
    d = p.Decoder()
    stream = b"\x00\x0f" + b"".join(b for b, _ in WORKED)
    got = []
    for i in range(0, len(stream), 5):
        got += d.feed(stream[i:i + 5])
    assert [(q.number, q.command) for q in got] == [(0, 0), (1, 2), (2, 4), (0, 30), (1, 32),
                                                    (2, 36), (3, 34)]
    assert all(isinstance(q, p.Packet) for q in got)


def test_a_corrupted_reply_is_reported_not_dropped():
    pkt = bytearray(p.encode(5, p.LL_STOP_ACK, bytes((0,))))
    pkt[-2] ^= 0x01                       # a flipped bit in the data
    (bad,) = p.Decoder().feed(bytes(pkt))
    assert isinstance(bad, p.BadPacket) and bad.command == p.LL_STOP_ACK and bad.number == 5


@pytest.mark.parametrize("current", [130.5, 150.0, -131.0, float("nan")])
def test_currents_beyond_the_devices_range_are_refused(current):
    with pytest.raises(ProtocolError, match="130"):
        p.point(100, current)


def test_current_off_the_half_milliamp_grid_is_refused():
    with pytest.raises(ProtocolError, match="0.5 mA"):
        p.point(100, 10.25)


@pytest.mark.parametrize("period_ms", [20000.0, 16384.0, 0.25, 10.25])
def test_periods_never_wrap(period_ms):
    with pytest.raises(ProtocolError, match="period"):
        p.ml_update_data({0: (period_ms, [(100, 5), (100, -5)])})


def test_longest_period_round_trips():
    data = p.ml_update_data({2: (16383.5, [(300, 12.5), (300, -12.5)])})
    assert p.ml_update_fields(data) == {2: (16383.5, [(300, 12.5), (300, -12.5)])}


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 260).map(lambda k: k * 0.5), st.integers(1, 4095), st.integers(0, 4095))
def test_biphasic_pulses_are_charge_balanced_and_within_range(current, width, gap):
    pts = p.biphasic_points(current, width, gap)
    assert sum(t * c for t, c in pts) == 0          # zero net charge by construction
    data = p.ll_channel_config_data(3, 1, pts)
    assert len(data) == 1 + 4 * len(pts)
    assert max(abs(c) for _, c in pts) <= p.MAX_CURRENT_MA


def test_a_stuffed_checksum_byte_equal_to_the_stop_byte_does_not_end_the_packet():
    # find a packet whose stuffed checksum or length carries 0x0F or 0xF0 after a 0x81
    for number in range(64):
        for c in range(0, 261):
            pkt = p.encode(number, p.LL_CHANNEL_CONFIG,
                           p.ll_channel_config_data(0, 0, p.biphasic_points(c / 2, 300, 100)))
            if p.STOP in pkt[1:9] or p.START in pkt[1:9]:
                (got,) = p.Decoder().feed(pkt)
                assert isinstance(got, p.Packet) and got.number == number
                return
    raise AssertionError("no such packet found")
