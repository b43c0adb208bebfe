"""The Leptrino 6-axis force sensor's serial protocol: frames, DLE stuffing, BCC, messages.

Pure byte handling, no I/O: :func:`encode_frame` builds a frame to send and
:class:`FrameDecoder` turns a byte stream (fed in arbitrary pieces, garbage included) into
frames, NAKs and corruption reports. :mod:`nmsid.drivers.leptrino` does the I/O.

Frame (both directions)::

    DLE STX | LEN TERM CMD RES/RSV  DATA... | DLE ETX BCC

* ``DLE`` = 0x10, ``STX`` = 0x02, ``ETX`` = 0x03. ``LEN`` counts the payload bytes between
  ``DLE STX`` and ``DLE ETX`` including itself (4 for a bare command). ``TERM`` is the
  terminal number, 0xFF. In a response the fourth byte is the result code (0 = OK).
* A payload byte equal to DLE is sent twice (DLE stuffing); the receiver keeps one.
* ``BCC`` = XOR of the (unstuffed) payload bytes and ``ETX``; the stuffing DLEs and the
  ``DLE`` of ``DLE ETX`` are not included.
* ``DLE NAK`` (0x10 0x15) is the sensor's negative acknowledgement of a garbled command.

Commands used here: 0x2A product information, 0x2B rated values, 0x30 one data record
(handshake), 0x32 start continuous output, 0x33 stop continuous output.

Data record (response to 0x30, and each frame of continuous output, LEN = 20): six int16
little-endian force / moment values (Fx, Fy, Fz, Mx, My, Mz), int16 temperature, a status
byte, a reserved byte. A raw value of 10000 is the axis' rated value, so
``value = raw * rated / 10000``. Status bits: 0 = calibration data in ROM corrupt,
1 = sensor fault, 2 = load above the rated value, 5 = external input detected (models
with an external input).

Sources (public; no Leptrino protocol manual was available to us):
Leptrino's own C sample as shipped in the ROS driver
``hiveground-ros-package/leptrino_force_torque`` (``pComResInternal.h``: command codes
0x2A/0x2B/0x32/0x33, result codes, record layouts; ``rs_comm.cpp`` and
``leptrino_force_torque.cpp``: stuffing, BCC with ETX and without DLEs, 460800 baud, rated
value x 1e-4, "maximum 1.2 kHz"), the Rust crate ``leptrino-force-torque-sensor``
(``parse.rs``: ``DLE NAK``; ``lib.rs``: handshake 0x30, raw 10000 = rated) and a Python
sample (status bits). The brief that started this module named 0x23 for "start
continuous"; every vendor-derived source above says 0x32, which is what is used.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

import numpy as np

DLE = 0x10
STX = 0x02
ETX = 0x03
NAK = 0x15
TERMINAL = 0xFF

RAW_AT_RATED = 10000.0
"""Raw data value that corresponds to the axis' rated load."""

PRODUCT_NAME_SIZE = 16
SERIAL_SIZE = 8
FIRMWARE_SIZE = 4
RATE_SIZE = 6
DATA_RECORD_LEN = 20
PRODUCT_INFO_LEN = 4 + PRODUCT_NAME_SIZE + SERIAL_SIZE + FIRMWARE_SIZE + RATE_SIZE
RATED_VALUES_LEN = 4 + 6 * 4


class Command(enum.IntEnum):
    PRODUCT_INFO = 0x2A
    RATED_VALUES = 0x2B
    HANDSHAKE = 0x30
    START_CONTINUOUS = 0x32
    STOP_CONTINUOUS = 0x33


class Result(enum.IntEnum):
    OK = 0x00
    BAD_LENGTH = 0x01
    UNDEFINED_COMMAND = 0x02
    BAD_VALUE = 0x03
    BAD_STATE = 0x04


class Status(enum.IntFlag):
    ROM_ERROR = 0x01
    SENSOR_FAULT = 0x02
    OVER_RATED = 0x04
    EXTERNAL_INPUT = 0x20


def bcc(payload: bytes) -> int:
    """Block check character of an unstuffed payload: XOR of its bytes and ETX."""
    value = ETX
    for byte in payload:
        value ^= byte
    return value


def encode_frame(payload: bytes) -> bytes:
    """Frame a payload: ``DLE STX``, the payload with every DLE doubled, ``DLE ETX``, BCC."""
    body = bytes(payload).replace(bytes([DLE]), bytes([DLE, DLE]))
    return bytes([DLE, STX]) + body + bytes([DLE, ETX, bcc(payload)])


def command_payload(command: Command, data: bytes = b"") -> bytes:
    """``LEN TERM CMD 0 DATA`` for a command to the sensor."""
    return bytes([4 + len(data), TERMINAL, int(command), 0]) + bytes(data)


def encode_command(command: Command, data: bytes = b"") -> bytes:
    return encode_frame(command_payload(command, data))


# -- decoding ---------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """A frame whose BCC matched. ``payload`` is unstuffed, ``LEN`` byte first."""

    payload: bytes

    @property
    def command(self) -> int:
        return self.payload[2] if len(self.payload) > 2 else -1

    @property
    def result(self) -> int:
        return self.payload[3] if len(self.payload) > 3 else -1

    @property
    def data(self) -> bytes:
        return self.payload[4:]


@dataclass(frozen=True)
class Nak:
    """``DLE NAK``: the sensor did not understand the last command."""


@dataclass(frozen=True)
class Corrupt:
    """Bytes that looked like a frame but failed a check (``reason`` says which).

    ``length`` is how many payload bytes had been received: a corrupt frame at least as
    long as a data record most likely was one (a sample is lost); a short one is usually
    line noise that happened to contain ``DLE STX``.
    """

    reason: str
    length: int = 0


class _State(enum.Enum):
    IDLE = 0
    AFTER_DLE = 1
    DATA = 2
    DATA_AFTER_DLE = 3
    BCC = 4


class FrameDecoder:
    """Incremental decoder: feed any pieces of the byte stream, get complete events.

    Bytes outside a frame are skipped (and counted in ``garbage_bytes``). A ``DLE STX``
    inside a frame restarts the frame (the previous one is reported as corrupt), as the
    vendor's sample receiver does, so one lost byte costs at most one frame.
    """

    MAX_PAYLOAD = 255

    def __init__(self):
        self._state = _State.IDLE
        self._buf = bytearray()
        self.garbage_bytes = 0

    def feed(self, data: bytes) -> list[Frame | Nak | Corrupt]:
        events: list[Frame | Nak | Corrupt] = []
        for byte in data:
            state = self._state
            if state is _State.IDLE:
                if byte == DLE:
                    self._state = _State.AFTER_DLE
                else:
                    self.garbage_bytes += 1
            elif state is _State.AFTER_DLE:
                if byte == STX:
                    self._buf.clear()
                    self._state = _State.DATA
                elif byte == NAK:
                    events.append(Nak())
                    self._state = _State.IDLE
                elif byte == DLE:
                    self.garbage_bytes += 1  # stay: this DLE may start a frame
                else:
                    self.garbage_bytes += 2
                    self._state = _State.IDLE
            elif state is _State.DATA:
                if byte == DLE:
                    self._state = _State.DATA_AFTER_DLE
                else:
                    self._append(byte, events)
            elif state is _State.DATA_AFTER_DLE:
                if byte == DLE:
                    self._state = _State.DATA
                    self._append(byte, events)
                elif byte == ETX:
                    self._state = _State.BCC
                elif byte == STX:
                    events.append(Corrupt("frame restarted by DLE STX before DLE ETX",
                                          len(self._buf)))
                    self._buf.clear()
                    self._state = _State.DATA
                else:
                    events.append(Corrupt(f"lone DLE followed by 0x{byte:02X} inside a "
                                          "frame", len(self._buf)))
                    self._buf.clear()
                    self._state = _State.IDLE
            else:  # BCC
                payload = bytes(self._buf)
                self._buf.clear()
                self._state = _State.IDLE
                if byte != bcc(payload):
                    events.append(Corrupt(f"BCC mismatch (got 0x{byte:02X}, computed "
                                          f"0x{bcc(payload):02X})", len(payload)))
                elif not payload or payload[0] != len(payload):
                    events.append(Corrupt(f"LEN byte {payload[0] if payload else None} "
                                          f"does not match the {len(payload)} payload "
                                          "bytes", len(payload)))
                else:
                    events.append(Frame(payload))
        return events

    def _append(self, byte: int, events: list) -> None:
        if len(self._buf) >= self.MAX_PAYLOAD:
            events.append(Corrupt("frame longer than 255 bytes without DLE ETX",
                                  len(self._buf)))
            self._buf.clear()
            self._state = _State.IDLE
            return
        self._buf.append(byte)


# -- messages ---------------------------------------------------------------------
@dataclass(frozen=True)
class ProductInfo:
    model: str
    serial: str
    firmware: str
    output_rate_Hz: float
    """The rate the sensor reports for continuous output (``nan`` if unparsable)."""


@dataclass(frozen=True)
class DataRecord:
    raw: tuple[int, int, int, int, int, int]
    temperature_raw: int
    status: Status


def _text(data: bytes) -> str:
    return data.split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()


def parse_product_info(frame: Frame) -> ProductInfo:
    data = frame.data
    need = PRODUCT_INFO_LEN - 4
    if len(data) < need:
        raise ValueError(f"product information frame has {len(data)} data bytes, "
                         f"expected {need}")
    o = 0
    model = _text(data[o:o + PRODUCT_NAME_SIZE]); o += PRODUCT_NAME_SIZE
    serial = _text(data[o:o + SERIAL_SIZE]); o += SERIAL_SIZE
    firmware = _text(data[o:o + FIRMWARE_SIZE]); o += FIRMWARE_SIZE
    rate_text = _text(data[o:o + RATE_SIZE])
    digits = "".join(ch for ch in rate_text if ch.isdigit() or ch == ".")
    try:
        rate = float(digits) * (1000.0 if "k" in rate_text.lower() else 1.0)
    except ValueError:
        rate = float("nan")
    return ProductInfo(model=model, serial=serial, firmware=firmware, output_rate_Hz=rate)


def parse_rated_values(frame: Frame) -> np.ndarray:
    data = frame.data
    if len(data) < 24:
        raise ValueError(f"rated-value frame has {len(data)} data bytes, expected 24")
    return np.array(struct.unpack("<6f", data[:24]), dtype=np.float64)


def parse_data_record(frame: Frame) -> DataRecord:
    data = frame.data
    if len(data) < DATA_RECORD_LEN - 4:
        raise ValueError(f"data frame has {len(data)} data bytes, expected "
                         f"{DATA_RECORD_LEN - 4}")
    values = struct.unpack("<6hhBB", data[:16])
    return DataRecord(raw=tuple(values[:6]), temperature_raw=values[6],
                      status=Status(values[7]))
