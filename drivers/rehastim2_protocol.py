"""The ScienceMode2 serial protocol of the Hasomed RehaStim2, encoded and decoded byte by byte.

Written from Hasomed's "ScienceMode2 - RehaStim2 Stimulation Device, Description and
Protocol", version 1.24, 2012-12-12 (``ScienceMode/ScienceMode2``, folder
``02_Description Protocol``; cited below as *SM2* with its section). Pure functions and
constants: no port, no thread. The driver (:mod:`nmsid.drivers.rehastim2`) and the fake
device (``nmsid.testing.fakes.fake_rehastim2``) both use the framing; the fake's behaviour
(modes, acknowledgements, watchdog, errors) is written separately from the description.

Why an own codec rather than pysciencemode: pysciencemode 1.1.5 drives the device from its
own threads and prints to the terminal, and its framing also escapes 0x55 and 0x0A, which
SM2 2.2 does not list; the rig needs every acknowledgement and stimulation error in its own
interlock loop, and a codec of ~150 lines that follows SM2 exactly is easier to review than
an adapter around a library's threads.
"""

from __future__ import annotations

from dataclasses import dataclass

from nmsid.drivers.errors import ProtocolError

# -- SM2 2.1, Table 4: serial settings ------------------------------------------------------
BAUDRATE = 460_800
"""8 data bits, 1 stop bit, even parity, no flow control (SM2 Table 4)."""

# -- SM2 2.2, Table 6: byte constants --------------------------------------------------------
START = 0xF0
STOP = 0x0F
STUFFING_BYTE = 0x81
STUFFING_KEY = 0x55
_ESCAPED = (START, STOP, STUFFING_BYTE)
"""SM2 2.2: "Every constant from Table 6, except the stuffing key, is escaped"."""
MAX_COMMAND_DATA = 60
"""SM2 Table 5: command data < 61 bytes."""

# -- SM2 2.3, Table 7: timeouts ---------------------------------------------------------------
INIT_REPETITION_S = 0.5
WATCHDOG_TIMEOUT_S = 1.2
MAX_RESPONSE_S = 0.1

# -- SM2 3.1 and 3.3: command numbers ----------------------------------------------------------
INIT, INIT_ACK, UNKNOWN_COMMAND, WATCHDOG = 1, 2, 3, 4
GET_STIM_MODE, GET_STIM_MODE_ACK = 10, 11
INIT_CLM, INIT_CLM_ACK = 30, 31
START_CLM, START_CLM_ACK = 32, 33
STOP_CLM, STOP_CLM_ACK = 34, 35
SINGLE_PULSE, SINGLE_PULSE_ACK = 36, 37
STIMULATION_ERROR = 38

# -- SM2 1.2 Table 1 and 4.3: limits -----------------------------------------------------------
N_CHANNELS = 8
MAX_CURRENT_MA = 130
"""SM2 Table 1 and 4.3 StartChannelListMode: current [0, 130] mA, whole mA."""
MIN_PULSE_WIDTH_US, MAX_PULSE_WIDTH_US = 20, 500
"""SM2 4.3: pulse width [0, 500] us, "in current version [20, 500] us"."""
INTERPHASE_US = 100
"""SM2 1.2, Figure 2: a fixed pause of 100 us between the two phases."""
MIN_MAIN_INTERVAL_MS = 8.0
"""SM2 4.3 InitChannelListMode: "the minimum main stimulation interval is 8 ms"."""
MAX_RATE_HZ = 50.0
"""SM2 Table 1: frequency [1, 50] Hz for 8 channels."""

TRANSFER_ERROR, WRONG_MODE, BUSY = -1, -3, -8
"""SM2 5.1 result codes the driver acts on (4.3: an ack carrying -1 was not executed)."""
#: SM2 5.1: error codes of the response commands.
RESULT_TEXT = {0: "no error", -1: "transfer error (checksum or length)", -2: "parameter error",
               -3: "wrong mode error", -4: "Motomed connection error",
               -5: "incompatible protocol version", -6: "invalid Motomed trainer",
               -7: "Motomed busy error", -8: "busy error"}
#: SM2 4.3 StimulationError: the device has stopped stimulation and reset to start mode.
STIM_ERROR_TEXT = {-1: "emergency switch activated / not connected", -2: "electrode error",
                   -3: "stimulation module error"}


def crc8(data: bytes) -> int:
    """CRC-8-CCITT, x^8 + x^2 + x + 1 (0x07), initial value 0 (SM2 2.2)."""
    crc = 0
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def stuff(data: bytes) -> bytes:
    """Escape each constant byte as ``0x81, byte ^ 0x55`` (SM2 2.2: 0xF0 -> 0x81 0xA5)."""
    out = bytearray()
    for b in data:
        if b in _ESCAPED:
            out += bytes((STUFFING_BYTE, b ^ STUFFING_KEY))
        else:
            out.append(b)
    return bytes(out)


def unstuff(data: bytes) -> bytes:
    out = bytearray()
    it = iter(data)
    for b in it:
        if b == STUFFING_BYTE:
            nxt = next(it, None)
            if nxt is None:
                raise ProtocolError("RehaStim2 packet ends in a stuffing byte (SM2 2.2)")
            out.append(nxt ^ STUFFING_KEY)
        else:
            out.append(b)
    return bytes(out)


def s8(value: int) -> int:
    """A signed result byte (two's complement) as an int."""
    return value - 256 if value > 127 else value


def u8(value: int) -> int:
    return value & 0xFF


@dataclass(frozen=True)
class Packet:
    """One decoded packet: packet number, command number and command data (SM2 Table 5)."""

    number: int
    command: int
    data: bytes = b""

    @property
    def result(self) -> int:
        """Byte 7 of a response as a signed result code (SM2 5.1)."""
        return s8(self.data[0]) if self.data else 0


def encode(number: int, command: int, data: bytes = b"") -> bytes:
    """The bytes of one packet (SM2 2.2, Table 5 and "The First Bytes" of 4)."""
    if len(data) > MAX_COMMAND_DATA:
        raise ValueError(f"command data of {len(data)} bytes; SM2 allows < 61")
    payload = stuff(bytes((number & 0xFF, command & 0xFF)) + bytes(data))
    return bytes((START, STUFFING_BYTE, crc8(payload) ^ STUFFING_KEY,
                  STUFFING_BYTE, len(payload) ^ STUFFING_KEY)) + payload + bytes((STOP,))


class Decoder:
    """Feed received bytes, take whole packets (SM2 2.2 and 5.2 "Packet frame error").

    A packet is parsed by position: start byte, stuffing byte, checksum, stuffing byte,
    data length, ``length`` bytes of stuffed payload, stop byte. The checksum and length
    are XORed with the key (SM2 2.2: "always stuffed"), so either may equal a constant;
    only the payload never does.
    """

    def __init__(self):
        self._buf = bytearray()
        self.rejected = 0
        """Packets dropped for a bad frame, checksum or length (SM2 5.2)."""

    def feed(self, data: bytes) -> list[Packet]:
        self._buf += data
        out: list[Packet] = []
        while True:
            try:
                i = self._buf.index(START)
            except ValueError:
                self._buf.clear()
                return out
            del self._buf[:i]
            if len(self._buf) < 5:
                return out
            if self._buf[1] != STUFFING_BYTE or self._buf[3] != STUFFING_BYTE:
                del self._buf[:1]
                self.rejected += 1
                continue
            length = self._buf[4] ^ STUFFING_KEY
            end = 5 + length
            if len(self._buf) < end + 1:
                second = self._buf.find(bytes((START,)), 5)
                if second != -1:   # SM2 5.2: rejected up to the second start byte
                    del self._buf[:second]
                    self.rejected += 1
                    continue
                return out
            frame = bytes(self._buf[:end + 1])
            pkt = _frame(frame)
            if pkt is None:
                del self._buf[:1]
                self.rejected += 1
                continue
            del self._buf[:end + 1]
            out.append(pkt)


def _frame(frame: bytes) -> Packet | None:
    checksum, length = frame[2] ^ STUFFING_KEY, frame[4] ^ STUFFING_KEY
    payload = frame[5:-1]
    if frame[-1] != STOP or len(payload) != length or START in payload or STOP in payload \
            or crc8(payload) != checksum:
        return None
    try:
        raw = unstuff(payload)
    except ProtocolError:
        return None
    if len(raw) < 2:
        return None
    return Packet(raw[0], raw[1], raw[2:])


# -- command data (SM2 4.3) ---------------------------------------------------------------------
def main_interval_code(rate_Hz: float) -> int:
    """``Main stimulation interval coded``: interval = code x 0.5 ms + 1 ms (SM2 4.3).

    Raises
    ------
    ValueError
        If 1000 / rate_Hz ms is not 1 ms plus a whole number of 0.5 ms, or below 8 ms.
    """
    t1_ms = 1000.0 / rate_Hz
    code = (t1_ms - 1.0) / 0.5
    if abs(code - round(code)) > 1e-6 or t1_ms < MIN_MAIN_INTERVAL_MS - 1e-9 \
            or round(code) > 2048:
        raise ValueError(f"pulse rate {rate_Hz:g} Hz: the RehaStim2's main stimulation "
                         "interval is 1 ms + k x 0.5 ms, 8 .. 1025 ms (SM2 4.3)")
    return round(code)


def init_clm_data(channels: tuple[int, ...], rate_Hz: float, *,
                  inter_pulse_ms: float = 8.0) -> bytes:
    """Command data of InitChannelListMode: continuous mode, single pulses (SM2 4.3)."""
    mask = 0
    for ch in channels:
        if not 1 <= ch <= N_CHANNELS:
            raise ValueError(f"RehaStim2 channel {ch}: valid 1 .. 8 (SM2 Table 3)")
        mask |= 1 << (ch - 1)
    ipi = round((inter_pulse_ms - 1.5) / 0.5)
    code = main_interval_code(rate_Hz)
    return bytes((0, mask, 0, ipi, code >> 8, code & 0xFF, 0))


def start_clm_data(pulses: list[tuple[int, int]]) -> bytes:
    """Command data of StartChannelListMode: per active channel, in increasing channel
    order, ``mode 0 (single), width MSB, width LSB, current`` (SM2 4.3).

    Raises
    ------
    ValueError
        For a width outside 20 .. 500 us or a current outside 0 .. 130 mA (SM2 4.3).
    """
    out = bytearray()
    for width_us, current_mA in pulses:
        if not MIN_PULSE_WIDTH_US <= width_us <= MAX_PULSE_WIDTH_US:
            raise ValueError(f"pulse width {width_us} us: valid 20 .. 500 us (SM2 4.3)")
        if not 0 <= current_mA <= MAX_CURRENT_MA:
            raise ValueError(f"current {current_mA} mA: valid 0 .. 130 mA (SM2 4.3)")
        out += bytes((0, width_us >> 8, width_us & 0xFF, current_mA))
    return bytes(out)


