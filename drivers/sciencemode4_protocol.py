"""The ScienceMode4 serial protocol of Hasomed's P24 and RehaMove3, encoded and decoded.

Sources, cited beside each choice:

* *IFU*: "P24 Science & P24 Module, Instructions for Use" v1.1, 2023-01-25
  (``ScienceMode/ScienceMode4_P24``, ``01_IFU_and_Protocol``), its ScienceMode chapter
  (Tables 1-27) and Technical Specification;
* *RM3*: "ScienceMode RehaMove3 Description and Protocol", 2018-04-21
  (``ScienceMode/ScienceMode3``, ``05_Protocol``), sections 1-7, with the worked packets of
  section 7 (the tests check this codec against every one of them);
* *smpt*: Hasomed's C library ``ScienceMode/ScienceMode4_c_library``
  (``ScienceMode_Library/src``), file named with the choice.

Where the documents disagree, the worked packets and the C library decide:

* byte order: RM3 2.2 says "little endian", but RM3 7's packets carry the length and the
  checksum most significant byte first, as the IFU ("big endian") and smpt
  (``smpt_insert_header``) do: big endian;
* Ml_get_current_data: IFU Table 19 numbers it 037 (ack 038); RM3 5.1, RM3 7.2's packet
  (``08 24``: command 36) and smpt (``Smpt_Cmd_Ml_Get_Current_Data = 36``) say 36 (ack 37):
  36;
* the current limit: the point format encodes -150 .. 150 mA (IFU Table 15, RM3 4.2), the
  devices deliver 130 mA (IFU Technical Specification "0 - 130 mA"; RM3 1.2 "± 130 mA") and
  smpt refuses more (``smpt_is_valid_point``: ``|current| > 130``): 130 mA, refused here
  before encoding;
* Reset_ack: RM3 3.1 "currently not send": this codec defines it, the driver never waits for
  it (nor sends Reset).

Why an own codec rather than a library: pyScienceMode wraps the C library through cffi and
runs on Windows only from Python 3.10 (issue 43); the pure-Python ``science_mode_4`` 0.0.23
read against these documents wraps periods over 16383 ms silently, uses the 0.25 ms fine bit
the other way round, accepts 150 mA, waits for the Reset_ack the RehaMove3 never sends and
drops replies with a bad checksum without a retry (a 5 s timeout). The framing is ~60 lines,
the commands nmsid uses ~80: smaller to review than an adapter around those defects.

Pure functions and constants: no port, no thread.
"""

from __future__ import annotations

from dataclasses import dataclass

from nmsid.drivers.errors import ProtocolError

# -- IFU Table 1, RM3 Table 1: serial settings ---------------------------------------------
BAUDRATE = 3_000_000
"""8 data bits, 2 stop bits, no parity, RTS/CTS flow control (IFU Table 1, RM3 Table 1)."""

# -- IFU Table 3, RM3 Table 3: byte constants ----------------------------------------------
START, STOP, STUFFING_BYTE, STUFFING_KEY = 0xF0, 0x0F, 0x81, 0x55
_SPECIAL = (START, STOP, STUFFING_BYTE)
"""IFU "Packet Structure": every constant but the stuffing key is escaped."""
HEADER_LEN = 11
"""Start byte 1 + stuffed length 4 + stuffed checksum 4 + command prefix 2 (IFU Table 2)."""
MAX_PACKET_LEN = 1200
"""IFU "Packet Structure": the longest packet, stuffing included."""

# -- command numbers: IFU Tables 4, 11, 19; smpt_definitions_data_types.h -----------------
LL_INIT, LL_INIT_ACK, LL_CHANNEL_CONFIG, LL_CHANNEL_CONFIG_ACK = 0, 1, 2, 3
LL_STOP, LL_STOP_ACK = 4, 5
ML_INIT, ML_INIT_ACK, ML_UPDATE, ML_UPDATE_ACK, ML_STOP, ML_STOP_ACK = 30, 31, 32, 33, 34, 35
ML_GET_CURRENT_DATA, ML_GET_CURRENT_DATA_ACK = 36, 37
"""36/37, not the IFU's 037/038: RM3 5.1 and 7.2 and smpt agree (module docstring)."""
GET_DEVICE_ID, GET_DEVICE_ID_ACK, RESET, RESET_ACK = 52, 53, 58, 59
GET_STIM_STATUS, GET_STIM_STATUS_ACK = 62, 63
GENERAL_ERROR, UNKNOWN_CMD = 66, 67

# -- IFU Table 27, RM3 6, smpt Smpt_Result: results ---------------------------------------
OK, TRANSFER_ERROR, PARAMETER_ERROR, NOT_INITIALIZED, ELECTRODE_ERROR = 0, 1, 2, 7, 10
PULSE_TIMEOUT_ERROR, PULSE_LOW_CURRENT_ERROR = 16, 28
RESULT_TEXT = {0: "no error", 1: "transfer error (checksum or length)", 2: "parameter error",
               3: "stimulation timeout", 4: "stimulation timeout", 7: "not initialized",
               10: "electrode error", 11: "unknown command", 16: "pulse timeout error",
               28: "pulse low current error"}

# -- IFU Table 7 (Get_stim_status_ack), RM3 3.3 ----------------------------------------------
STIM_NONE, STIM_LL, STIM_ML, STIM_ML_RUNNING = 0, 1, 2, 3

# -- the pulse's point definition: IFU Table 15, RM3 4.2, smpt_insert_ll_point --------------
MAX_POINT_US = 4095
"""A point lasts 0 .. 4095 us (12 bits)."""
MAX_CURRENT_MA = 130.0
"""The devices' output (IFU Technical Specification, RM3 1.2; smpt_is_valid_point)."""
STEP_MA = 0.5
"""f(x) = 2x + 300: 0.5 mA steps (IFU Table 15, RM3 4.2)."""
MAX_POINTS = 16
KEEPALIVE_TIMEOUT_S = 2.0
"""Mid level: stimulation stops 2 s after the last Ml_update or Ml_get_current_data (IFU
"Mid-Level Update", RM3 5.1)."""
ML_MAX_PERIOD_MS = 16383.5
"""Ml_update period: 15 bits of 0.5 ms, 1 .. 32767 (IFU Table 22, RM3 5.2); more is refused,
never wrapped."""


def crc16(data: bytes) -> int:
    """CRC-CCITT (polynomial 0x1021, seed 0), as ``smpt_compute_checksum``."""
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def stuff(data: bytes) -> bytes:
    out = bytearray()
    for b in data:
        out += bytes((STUFFING_BYTE, b ^ STUFFING_KEY)) if b in _SPECIAL else bytes((b,))
    return bytes(out)


def unstuff(data: bytes) -> bytes:
    out, it = bytearray(), iter(data)
    for b in it:
        out.append(next(it, 0) ^ STUFFING_KEY if b == STUFFING_BYTE else b)
    return bytes(out)


def encode(number: int, command: int, data: bytes = b"") -> bytes:
    """One packet (IFU Table 2; smpt ``smpt_build_packet``): the command prefix is 6 bits of
    packet number and 10 bits of command; the prefix and data are stuffed; the checksum is
    the CRC of the *stuffed* prefix and data; length and checksum are always stuffed, so
    they take 4 bytes each (IFU "Packet Structure")."""
    if not 0 <= number <= 63 or not 0 <= command < 1024:
        raise ProtocolError(f"ScienceMode4: packet number {number} / command {command} out "
                            "of range (6 and 10 bits, IFU Table 2)")
    body = stuff(bytes((((number << 2) & 0xFC) | ((command >> 8) & 0x03), command & 0xFF))
                 + data)
    length = 1 + 8 + len(body) + 1
    if length > MAX_PACKET_LEN:
        raise ProtocolError(f"ScienceMode4 packet of {length} bytes (max {MAX_PACKET_LEN})")
    cs = crc16(body)
    head = bytes((START, STUFFING_BYTE, (length >> 8) ^ STUFFING_KEY,
                  STUFFING_BYTE, (length & 0xFF) ^ STUFFING_KEY,
                  STUFFING_BYTE, (cs >> 8) ^ STUFFING_KEY, STUFFING_BYTE,
                  (cs & 0xFF) ^ STUFFING_KEY))
    return head + body + bytes((STOP,))


@dataclass(frozen=True)
class Packet:
    number: int
    command: int
    data: bytes
    """The command data, unstuffed."""

    @property
    def result(self) -> int:
        return self.data[0] if self.data else 0


@dataclass(frozen=True)
class BadPacket:
    """A framed packet whose checksum or length is wrong (IFU Table 27 "transfer error"):
    the receiver answers it (device) or treats it as lost and asks again (host)."""

    number: int
    command: int


class Decoder:
    """Packets out of a byte stream: start byte to stop byte (smpt ``smpt_find_packet``);
    a start byte inside a packet restarts it; a packet with a bad checksum or length comes
    out as a :class:`BadPacket` (never silently dropped)."""

    def __init__(self):
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[Packet | BadPacket]:
        self.buf += data
        out: list[Packet | BadPacket] = []
        while True:
            if START not in self.buf:
                self.buf.clear()
                return out
            del self.buf[:self.buf.index(START)]
            end = _find_special(self.buf)
            if end is None:
                return out
            if self.buf[end] == START:   # a new start before the stop: the first is broken
                del self.buf[:end]
                continue
            frame = bytes(self.buf[:end + 1])
            del self.buf[:end + 1]
            pkt = _frame(frame)
            if pkt is not None:
                out.append(pkt)


def _find_special(buf: bytearray) -> int | None:
    """Index of the first start or stop byte after ``buf[0]`` that is not the byte after a
    stuffing byte (smpt ``smpt_find_packet``: "ignore_next_byte"; a stuffed length or
    checksum byte may equal 0x0F or 0xF0)."""
    i = 1
    while i < len(buf):
        b = buf[i]
        if b == STUFFING_BYTE:
            i += 2
            continue
        if b in (START, STOP):
            return i
        i += 1
    return None


def _frame(frame: bytes) -> Packet | BadPacket | None:
    if len(frame) < HEADER_LEN + 1 or frame[1] != STUFFING_BYTE or frame[3] != STUFFING_BYTE \
            or frame[5] != STUFFING_BYTE or frame[7] != STUFFING_BYTE:
        return None                      # not a packet at all: nothing to answer
    body = frame[9:-1]
    raw = unstuff(body)
    if len(raw) < 2:
        return None
    number, command = raw[0] >> 2, ((raw[0] & 0x03) << 8) | raw[1]
    length = ((frame[2] ^ STUFFING_KEY) << 8) | (frame[4] ^ STUFFING_KEY)
    cs = ((frame[6] ^ STUFFING_KEY) << 8) | (frame[8] ^ STUFFING_KEY)
    if length != len(frame) or cs != crc16(body):   # smpt_check_length, smpt_check_checksum
        return BadPacket(number, command)
    return Packet(number, command, raw[2:])


# -- commands -------------------------------------------------------------------------------
def ll_init_data(high_voltage: int = 0) -> bytes:
    """Ll_init (IFU Table 12, smpt ``insert_ll_init``): no measurement, high voltage
    0 = standard 150 V."""
    return bytes((((0 & 0x07) << 4) | ((high_voltage & 0x07) << 1),))


def check_point_current(current_mA: float) -> float:
    """A point's current, refused outside +-130 mA or off the 0.5 mA grid (before encoding,
    never clipped or wrapped)."""
    c = float(current_mA)
    if not abs(c) <= MAX_CURRENT_MA:
        raise ProtocolError(f"ScienceMode4 point current {c!r} mA: valid -130 .. 130 mA "
                            "(IFU Technical Specification; smpt_is_valid_point)")
    if abs(c / STEP_MA - round(c / STEP_MA)) > 1e-9:
        raise ProtocolError(f"ScienceMode4 point current {c!r} mA is not a multiple of "
                            "0.5 mA (IFU Table 15: f(x) = 2x + 300)")
    return c


def point(duration_us: int, current_mA: float) -> bytes:
    """One point (IFU Table 15, RM3 4.2; smpt ``smpt_insert_ll_point``): 12 bits duration,
    10 bits of 2 x current + 300, 10 reserved bits (interpolation 0)."""
    if not 0 <= int(duration_us) <= MAX_POINT_US or int(duration_us) != duration_us:
        raise ProtocolError(f"ScienceMode4 point of {duration_us!r} us: valid whole "
                            f"0 .. {MAX_POINT_US} us (IFU Table 15)")
    t = int(duration_us)
    c = int(round(check_point_current(current_mA) * 2 + 300))
    return bytes((t >> 4, ((t << 4) & 0xF0) | ((c >> 6) & 0x0F), (c << 2) & 0xFC, 0))


def biphasic_points(current_mA: float, width_us: int, interphase_us: int) -> list[
        tuple[int, float]]:
    """A charge-balanced biphasic pulse, by construction: +I for the width, the pause at 0,
    -I for the same width (RM3 7.1's example: 250 us 20 mA, 100 us 0 mA, 250 us -20 mA).
    The same current and the same width in both phases: zero net charge."""
    pts = [(width_us, current_mA)]
    if interphase_us:
        pts.append((interphase_us, 0.0))
    pts.append((width_us, -current_mA))
    return pts


def ll_channel_config_data(channel: int, connector: int,
                           points: list[tuple[int, float]] | None) -> bytes:
    """Ll_channel_config (IFU Table 14, RM3 4.2; smpt ``insert_ll_channel_config``): bit 7
    execute, bits 6-5 channel 0-3, bit 4 connector 0-1 (RehaMove3: reserved 0), bits 3-0
    number of points - 1; then the points. ``points`` None: no stimulation."""
    if not 0 <= channel <= 3 or connector not in (0, 1):
        raise ProtocolError(f"ScienceMode4 channel {channel} connector {connector}: valid "
                            "channel 0 .. 3, connector 0 .. 1 (IFU Table 14)")
    if points is not None and not 1 <= len(points) <= MAX_POINTS:
        raise ProtocolError(f"ScienceMode4: {len(points)} points, valid 1 .. 16 "
                            "(IFU Table 14)")
    n = 0 if not points else len(points) - 1
    head = bytes(((0x80 if points else 0) | (channel << 5) | (connector << 4) | n,))
    return head + b"".join(point(t, c) for t, c in (points or []))


def ml_update_data(channels: dict[int, tuple[float, list[tuple[int, float]]]],
                   ramp: int = 0) -> bytes:
    """Ml_update for channels 0 .. 7 (IFU Table 22; smpt ``smpt_utils_insert_ml_update``
    as RM3 7.2's packet shows it): one byte of channel bits (channels 0-7), then per active
    channel: points - 1 (high nibble) and ramp (low nibble), the period as 2 bytes of
    0.5 ms (15 bits, bit 0 reserved: value << 1), the points. ``channels``:
    ``{channel: (period_ms, points)}``. A period outside 0.5 .. 16383.5 ms or off the
    0.5 ms grid is refused, never wrapped (the ``science_mode_4`` defect)."""
    mask = 0
    out = bytearray()
    for ch in sorted(channels):
        if not 0 <= ch <= 7:
            raise ProtocolError(f"ScienceMode4 mid-level channel {ch}: valid 0 .. 7")
        period_ms, pts = channels[ch]
        x = period_ms * 2
        if not (1 <= x <= 32767 and abs(x - round(x)) < 1e-9):
            raise ProtocolError(f"ScienceMode4 period {period_ms!r} ms: valid 0.5 .. "
                                f"{ML_MAX_PERIOD_MS} ms in 0.5 ms steps (IFU Table 22)")
        if not 1 <= len(pts) <= MAX_POINTS or not 0 <= ramp <= 15:
            raise ProtocolError("ScienceMode4: 1 .. 16 points, ramp 0 .. 15 (IFU Table 22)")
        mask |= 1 << ch
        v = int(round(x)) << 1
        out += bytes((((len(pts) - 1) << 4) | ramp, (v >> 8) & 0xFF, v & 0xFF))
        out += b"".join(point(t, c) for t, c in pts)
    return bytes((mask,)) + bytes(out)


def ml_update_fields(data: bytes) -> dict[int, tuple[float, list[tuple[int, float]]]]:
    """The inverse of :func:`ml_update_data` (the fake device reads what the host sent)."""
    mask, i, out = data[0], 1, {}
    for ch in range(8):
        if not mask & (1 << ch):
            continue
        n = (data[i] >> 4) + 1
        period_ms = (((data[i + 1] << 8) | data[i + 2]) >> 1) / 2
        i += 3
        pts = []
        for _ in range(n):
            b = data[i:i + 4]
            t = (b[0] << 4) | (b[1] >> 4)
            c = (((b[1] & 0x0F) << 6) | (b[2] >> 2))
            pts.append((t, (c - 300) / 2))
            i += 4
        out[ch] = (period_ms, pts)
    return out


def ml_get_current_data_data() -> bytes:
    """Ml_get_current_data with the stimulation data selected (RM3 5.2: "0x2")."""
    return bytes((2,))
