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

Commands used here: 0x2A product information, 0x2B rated values, 0xB6 digital filter,
0x30 one data record (handshake), 0x32 start continuous output (acknowledged by a bare
response before the records, specification v1.13 6.2), 0x33 stop continuous output. A
command answered ``DLE NAK`` is sent again (2.4.3: "the host must resend the command").

Source of record since round two: Leptrino's "力覚センサ通信フォーマット仕様書" (communication
format specification) Ver 1.13 and the CFS-series manual No.M000104, public in
``hiveground-ros-package/leptrino_force_torque`` (``doc/protocal.pdf``, ``doc/manual.pdf``).
Specification 5.1's product information has NO rate field (LEN $20: model, serial,
firmware); the rate field below comes from the C sample only.

Data record (response to 0x30, and each frame of continuous output, LEN = 20): six int16
little-endian force / moment values (Fx, Fy, Fz, Mx, My, Mz), two reserved bytes, a status
byte, a reserved byte (specification 6.1). A raw value of 10000 is the axis' rated value,
so ``value = raw * rated / 10000``. Status bits: 0 = calibration data in ROM corrupt,
1 = sensor fault, 2 = load above the rated value; bits 3-7 are reserved and undefined
(6.1). :func:`parse_data_record` masks them off and ignores the reserved bytes, so no
flag, no sync and no "temperature" can ever come from them (an earlier reading took bit 5
as an external input and the two bytes after Mz as a temperature: neither is in 6.1).

Product information (0x2A, ``ST_R_GET_INF`` in ``pComResInternal.h``): model (16 bytes),
serial (8), firmware version (4) and output rate (6, text; ``FREQ_SIZE`` in
``pCommon.h``). Older firmware ends the reply after the firmware version (28 data bytes):
that reply is accepted and the rate is reported as not stated (``rate_stated = False``);
the driver then uses the nominal rate and says so in the log. The rate text is parsed
strictly by :func:`parse_rate_text`: a decimal number, optionally followed by ``Hz``,
``k`` or ``kHz`` (``1200``, ``1200Hz``, ``1.2k``, ``1.2kHz``); anything else (``1k2``,
``12e2``) is refused with a :class:`~nmsid.drivers.errors.ProtocolError` naming the device and
the reply. Every parse error raises that driver error, never a bare ``ValueError``.

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
import re
import struct
from dataclasses import dataclass

import numpy as np

from nmsid.drivers.errors import ProtocolError

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
PRODUCT_INFO_LEN_NO_RATE = PRODUCT_INFO_LEN - RATE_SIZE
"""Older firmware: the reply ends after the firmware version (28 data bytes)."""


class Command(enum.IntEnum):
    PRODUCT_INFO = 0x2A
    RATED_VALUES = 0x2B
    FILTER = 0xB6
    """Specification v1.13, 5.3: read the FIR digital filter's cut-off (setting is 0xA6)."""
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


FULL_SCALE_RAW = 32000
"""Specification v1.13, 6: data "-32000 .. +32000"; "a force above 3.2 times the rating is
also +-32000": a record at +-32000 is clipped, the true force is unknown."""

FILTER_CUTOFF_HZ = {0x00: None, 0x01: 10.0, 0x02: 100.0, 0x03: 200.0}
"""Specification v1.13, 5.3: filter setting $00 OFF, $01 10 Hz, $02 100 Hz, $03 200 Hz."""

DOCUMENTED_STATUS_BITS = int(Status.ROM_ERROR | Status.SENSOR_FAULT | Status.OVER_RATED)
"""Bits 0, 1, 2 (specification 6.1); bits 3-7 are reserved (undefined) and masked off."""


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
    """The rate the sensor reports for continuous output (``nan`` if not stated)."""
    rate_stated: bool = True
    """False when the reply had no rate field (older firmware) or an empty one."""
    rate_text: str = ""


@dataclass(frozen=True)
class FilterSetting:
    """The sensor's FIR digital filter (0xB6 reply, specification v1.13, 5.3)."""

    code: int
    cutoff_Hz: float | None
    """None: filter OFF."""

    def describe(self) -> str:
        return "off" if self.cutoff_Hz is None else f"FIR low-pass {self.cutoff_Hz:g} Hz"


def parse_filter(frame: Frame, device: str = "Leptrino sensor") -> FilterSetting:
    """The filter setting from a 0xB6 reply (LEN 8: setting byte, 3 reserved bytes).

    Raises
    ------
    ProtocolError
        A reply without the setting byte or with a code outside $00..$03.
    """
    data = frame.data
    if len(data) < 1 or data[0] not in FILTER_CUTOFF_HZ:
        raise ProtocolError(f"{device}: digital-filter reply {data!r} is not one of $00 OFF, "
                            "$01 10 Hz, $02 100 Hz, $03 200 Hz (specification 5.3)")
    return FilterSetting(code=data[0], cutoff_Hz=FILTER_CUTOFF_HZ[data[0]])


@dataclass(frozen=True)
class DataRecord:
    raw: tuple[int, int, int, int, int, int]
    status: Status
    """Documented bits 0-2 only (reserved bits 3-7 masked off, specification 6.1)."""


def _text(data: bytes) -> str:
    return data.split(b"\x00", 1)[0].decode("ascii", errors="replace").strip()


_RATE_RE = re.compile(r"(?P<num>[0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*(?P<unit>k|kh|khz|h|hz)?",
                      re.IGNORECASE)


def parse_rate_text(text: str, device: str = "Leptrino sensor") -> float:
    """The output rate in Hz from the product information's rate text, parsed leniently.

    The field is 6 bytes of text (``FREQ_SIZE``), so a unit is often cut short. Accepted: a
    decimal number, optionally followed by ``H``, ``Hz``, ``k``, ``kH`` or ``kHz`` (any
    case, spaces allowed before the unit): ``1200``, ``1200 H``, ``1200Hz``, ``1.2k``,
    ``1.2 kH``, ``1.2kHz``. The stated rate is informative only: the driver MEASURES the
    record rate (:meth:`nmsid.drivers.leptrino.LeptrinoAcquisition.measure_rate`).

    Raises
    ------
    ProtocolError
        For any other text (``1k2``, ``12e2``, ``fast``) or a rate that is not positive; the
        message names ``device`` and the text.
    """
    m = _RATE_RE.fullmatch(text.strip())
    rate = float("nan")
    if m is not None:
        rate = float(m.group("num"))
        if (m.group("unit") or "").lower().startswith("k"):
            rate *= 1000.0
    if not rate > 0:
        raise ProtocolError(
            f"{device}: product information states the output rate as {text!r}, which is "
            "not a rate; expected a number optionally followed by Hz, k or kHz "
            "(e.g. '1200', '1200Hz', '1.2kHz')")
    return rate


def parse_product_info(frame: Frame, device: str = "Leptrino sensor") -> ProductInfo:
    """Model, serial, firmware and output rate from a 0x2A reply (28 or 34 data bytes).

    Raises
    ------
    ProtocolError
        If the reply is shorter than 28 data bytes or states an unreadable rate.
    """
    data = frame.data
    need = PRODUCT_INFO_LEN_NO_RATE - 4
    if len(data) < need:
        raise ProtocolError(f"{device}: product information reply has {len(data)} data "
                            f"bytes ({data!r}); expected {need} (older firmware) or "
                            f"{PRODUCT_INFO_LEN - 4}")
    o = 0
    model = _text(data[o:o + PRODUCT_NAME_SIZE]); o += PRODUCT_NAME_SIZE
    serial = _text(data[o:o + SERIAL_SIZE]); o += SERIAL_SIZE
    firmware = _text(data[o:o + FIRMWARE_SIZE]); o += FIRMWARE_SIZE
    rate_text = _text(data[o:o + RATE_SIZE])
    if not rate_text:  # no rate field (older firmware) or an empty one
        return ProductInfo(model=model, serial=serial, firmware=firmware,
                           output_rate_Hz=float("nan"), rate_stated=False)
    rate = parse_rate_text(rate_text, f"{device} ({model or 'unknown model'})")
    return ProductInfo(model=model, serial=serial, firmware=firmware, output_rate_Hz=rate,
                       rate_stated=True, rate_text=rate_text)


def parse_rated_values(frame: Frame, device: str = "Leptrino sensor") -> np.ndarray:
    """Rated Fx, Fy, Fz, Mx, My, Mz (6 little-endian float32, ``ST_R_LEP_GET_LIMIT``)."""
    data = frame.data
    if len(data) < 24:
        raise ProtocolError(f"{device}: rated-value reply has {len(data)} data bytes "
                            f"({data!r}); expected 24")
    return np.array(struct.unpack("<6f", data[:24]), dtype=np.float64)


def parse_data_record(frame: Frame, device: str = "Leptrino sensor") -> DataRecord:
    """One ``ST_R_DATA_GET_F`` record; the status keeps documented bits only."""
    data = frame.data
    if len(data) < DATA_RECORD_LEN - 4:
        raise ProtocolError(f"{device}: data record has {len(data)} data bytes; expected "
                            f"{DATA_RECORD_LEN - 4}")
    values = struct.unpack("<6h2xBx", data[:16])     # 6.1: 2 reserved bytes, status, 1
    return DataRecord(raw=tuple(values[:6]), status=Status(values[6] & DOCUMENTED_STATUS_BITS))
