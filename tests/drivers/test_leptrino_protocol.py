"""Frame codec of the Leptrino protocol: stuffing, BCC, resynchronisation."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.drivers.leptrino_protocol import (
    DLE,
    ETX,
    STX,
    Command,
    Corrupt,
    Frame,
    FrameDecoder,
    Nak,
    Status,
    bcc,
    encode_command,
    encode_frame,
    parse_data_record,
    parse_product_info,
    parse_rated_values,
)


def test_command_bytes_match_vendor_sample():
    # Leptrino's sample: LEN=4, TERM=0xFF, CMD, 0; BCC = 4^0xFF^CMD^0^ETX
    frame = encode_command(Command.START_CONTINUOUS)
    assert frame == bytes([DLE, STX, 4, 0xFF, 0x32, 0, DLE, ETX, 4 ^ 0xFF ^ 0x32 ^ ETX])


def test_dle_in_payload_is_doubled_and_not_counted_twice_in_bcc():
    payload = bytes([6, 0xFF, 0x10, 0x00, 0x10, 0x05])
    frame = encode_frame(payload)
    assert frame[2:-3] == bytes([6, 0xFF, 0x10, 0x10, 0x00, 0x10, 0x10, 0x05])
    expected = 0
    for b in payload:
        expected ^= b
    assert frame[-1] == expected ^ ETX
    assert FrameDecoder().feed(frame) == [Frame(payload)]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=40), min_size=1, max_size=5),
       st.binary(max_size=30), st.integers(1, 9))
def test_round_trip_any_payload_any_split_with_garbage(datas, garbage, piece):
    garbage = garbage.replace(bytes([DLE]), b"")  # garbage without DLE cannot fake a frame
    payloads = [bytes([4 + len(d), 0xFF, 0x32, 0]) + d for d in datas]
    stream = b"".join(garbage + encode_frame(p) for p in payloads)
    dec = FrameDecoder()
    events = []
    for i in range(0, len(stream), piece):
        events += dec.feed(stream[i:i + piece])
    assert events == [Frame(p) for p in payloads]
    assert dec.garbage_bytes == len(garbage) * len(payloads)


def test_corrupt_bcc_is_reported_and_next_frame_survives():
    good = encode_command(Command.PRODUCT_INFO)
    bad = bytearray(good)
    bad[-1] ^= 0xFF
    events = FrameDecoder().feed(bytes(bad) + good)
    assert isinstance(events[0], Corrupt) and "BCC" in events[0].reason
    assert events[1] == Frame(bytes([4, 0xFF, 0x2A, 0]))


def test_restart_inside_frame_and_lone_dle_and_nak():
    dec = FrameDecoder()
    good = encode_command(Command.RATED_VALUES)
    events = dec.feed(bytes([DLE, STX, 4, 0xFF]) + good)  # truncated frame then a good one
    assert isinstance(events[0], Corrupt) and events[1] == Frame(bytes([4, 0xFF, 0x2B, 0]))
    events = dec.feed(bytes([DLE, STX, 4, DLE, 0x07]) + good + bytes([DLE, 0x15]))
    assert isinstance(events[0], Corrupt) and "lone DLE" in events[0].reason
    assert events[1:] == [Frame(bytes([4, 0xFF, 0x2B, 0])), Nak()]


def test_len_mismatch_is_corrupt():
    payload = bytes([9, 0xFF, 0x30, 0])
    assert isinstance(FrameDecoder().feed(encode_frame(payload))[0], Corrupt)


def test_overlong_frame_is_dropped():
    events = FrameDecoder().feed(bytes([DLE, STX]) + bytes(300))
    assert any(isinstance(e, Corrupt) and "255" in e.reason for e in events)


def test_parse_messages():
    data = (b"PFS080YA501G6".ljust(16, b"\0") + b"AB12".ljust(8, b"\0") + b"1.07"
            + b"1.2kHz")
    info = parse_product_info(Frame(bytes([4 + len(data), 0xFF, 0x2A, 0]) + data))
    assert (info.model, info.serial, info.firmware, info.output_rate_Hz) == \
        ("PFS080YA501G6", "AB12", "1.07", 1200.0)
    rated = parse_rated_values(Frame(bytes([28, 0xFF, 0x2B, 0])
                                     + struct.pack("<6f", 500, 500, 1000, 10, 10, 10)))
    np.testing.assert_allclose(rated, [500, 500, 1000, 10, 10, 10])
    rec = parse_data_record(Frame(bytes([20, 0xFF, 0x32, 0])
                                  + struct.pack("<6hhBB", 10000, -1, 4112, 0, 0, 0, 25, 0x24, 0)))
    assert rec.raw[:3] == (10000, -1, 4112)
    assert rec.status & Status.OVER_RATED and int(rec.status) == 0x04   # bit 5 reserved
    assert bcc(b"") == ETX
