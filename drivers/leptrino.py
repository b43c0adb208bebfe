"""Leptrino 6-axis force sensor on its USB (virtual COM port) interface, via pyserial.

:class:`LeptrinoSensor` speaks the command protocol of :mod:`nmsid.drivers.leptrino_protocol`
(product information, rated values, start / stop continuous output) over a serial port;
:class:`LeptrinoAcquisition` wraps it as a :class:`nmsid.drivers.interfaces.ForceAcquisition`.

Rate: the sensor streams at its own fixed rate (about 1.2 kHz for this family; the
product-information reply states it). :meth:`LeptrinoAcquisition.configure` returns that
rate, never the one asked for, and ``drivers.hardware`` refuses a configuration that asks
this chain for 2000 Hz.

Time base: the digital interface has no hardware start trigger. With
``sync_on_external_input`` the stimulator's sync line is wired to the sensor's external
input and sample 0 is the first record whose status has the external-input bit; otherwise
a triggered start is aligned to the first record after :meth:`start` (host timing: one
record plus USB latency, logged as a warning).

Faults become :class:`~nmsid.drivers.interfaces.AcquisitionFlags`: status bits over-rated ->
``over_range``, sensor fault / ROM error -> ``sensor_fault``; frames lost to corruption ->
``overrun`` (a sample is missing, the time base would shift); a serial-port error
(cable pulled out) -> ``sensor_fault`` on every later read. A stalled stream returns
``None`` and the engine's watchdog trips.

Port settings (460800 baud, 8N1, no flow control) follow Leptrino's sample code, see
:mod:`nmsid.drivers.leptrino_protocol` for the sources.
"""

from __future__ import annotations

import logging
import time
from typing import Callable

import numpy as np

from nmsid.drivers.errors import DeviceNotFound, ProtocolError, VendorLibraryMissing
from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk
from nmsid.drivers.leptrino_protocol import (
    DATA_RECORD_LEN, RAW_AT_RATED, Command, Corrupt, DataRecord, Frame, FrameDecoder, Nak, ProductInfo,
    Result, Status, encode_command, parse_data_record, parse_product_info,
    parse_rated_values)

log = logging.getLogger(__name__)

DEFAULT_BAUD = 460800
NOMINAL_RATE_HZ = 1200.0
"""Used when the product information does not state a parsable rate."""


def _serial_module():
    try:
        import serial  # noqa: PLC0415 (lazy: vendor library)
    except ImportError:
        raise VendorLibraryMissing(
            "the Python package pyserial", "the Leptrino USB sensor and the serial E-stop",
            "install it with: pip install 'nmsid[serial]'") from None
    return serial


def open_serial(port: str, baudrate: int, timeout_s: float):
    """Open ``port`` (a device path or a pyserial URL) 8N1 without flow control.

    Raises
    ------
    DeviceNotFound
        If the port cannot be opened; the message names the port.
    """
    serial = _serial_module()
    try:
        return serial.serial_for_url(port, baudrate=baudrate, bytesize=8, parity="N",
                                     stopbits=1, timeout=timeout_s, rtscts=False,
                                     xonxoff=False)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceNotFound(f"cannot open serial port {port!r} for the Leptrino sensor: "
                             f"{exc}. Check the USB cable and the port name "
                             "(acquisition.leptrino.port)") from None


class LeptrinoSensor:
    """Command-level access to one sensor.

    Parameters
    ----------
    port : str
        Serial port (``COM5``, ``/dev/ttyACM0``) or pyserial URL.
    baudrate : int
    reply_timeout_s : float
        How long to wait for the reply to a command.
    retries : int
        Attempts per command when the reply is a NAK or a corrupt frame.
    serial_factory : callable, optional
        ``(port, baudrate, timeout_s) -> serial-like``; defaults to :func:`open_serial`.
    """

    def __init__(self, port: str, *, baudrate: int = DEFAULT_BAUD,
                 reply_timeout_s: float = 0.5, retries: int = 3,
                 serial_factory: Callable | None = None):
        self.port = port
        self.baudrate = baudrate
        self.reply_timeout_s = reply_timeout_s
        self.retries = retries
        self._factory = serial_factory or open_serial
        self._ser = None
        self._decoder = FrameDecoder()
        self._pending: list = []
        self.sent: list[Command] = []
        self.corrupt_frames = 0
        self.naks = 0

    # -- port ---------------------------------------------------------------------
    def open(self) -> None:
        if self._ser is None:
            self._ser = self._factory(self.port, self.baudrate, 0.01)
            self._decoder = FrameDecoder()
            self._pending.clear()

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a dead port: nothing more to do
                pass

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def _write(self, command: Command) -> None:
        if self._ser is None:
            raise ProtocolError(f"Leptrino port {self.port!r} is not open")
        self._ser.write(encode_command(command))
        self._ser.flush()
        self.sent.append(command)

    def poll(self, wait_s: float) -> list:
        """Read what has arrived (waiting up to ``wait_s`` for the first byte) and decode.

        Raises the serial library's exception (an ``OSError`` subclass) on a port error.
        """
        if self._ser is None:
            raise ProtocolError(f"Leptrino port {self.port!r} is not open")
        events = self._pending
        self._pending = []
        deadline = time.monotonic() + max(wait_s, 0.0)
        while True:
            waiting = self._ser.in_waiting
            data = self._ser.read(waiting if waiting else 1)
            if data:
                events.extend(self._decoder.feed(data))
                if not self._ser.in_waiting:
                    break
            elif events or time.monotonic() >= deadline:
                break
        for ev in events:
            if isinstance(ev, Corrupt):
                self.corrupt_frames += 1
                log.debug("Leptrino %s: corrupt frame: %s", self.port, ev.reason)
            elif isinstance(ev, Nak):
                self.naks += 1
        return events

    # -- commands -----------------------------------------------------------------
    def request(self, command: Command) -> Frame:
        """Send ``command`` and return its reply frame (data records are skipped).

        Raises
        ------
        ProtocolError
            After ``retries`` NAKs / corrupt replies / timeouts, or on a result code other
            than OK; the message names the command.
        """
        last_problem = "no reply"
        for _attempt in range(self.retries):
            self._write(command)
            deadline = time.monotonic() + self.reply_timeout_s
            retry = False
            while time.monotonic() < deadline and not retry:
                for ev in self.poll(min(0.02, max(deadline - time.monotonic(), 0))):
                    if isinstance(ev, Nak):
                        last_problem, retry = "NAK (sensor rejected the frame)", True
                    elif isinstance(ev, Corrupt):
                        last_problem, retry = f"corrupt reply: {ev.reason}", True
                    elif isinstance(ev, Frame) and ev.command == int(command):
                        if ev.result != Result.OK:
                            try:
                                name = Result(ev.result).name
                            except ValueError:
                                name = f"0x{ev.result:02X}"
                            raise ProtocolError(
                                f"Leptrino {self.port!r} answered {command.name} "
                                f"(0x{int(command):02X}) with error result {name}")
                        return ev
                    if retry:
                        break
            log.warning("Leptrino %s: %s to %s, retrying", self.port, last_problem,
                        command.name)
        raise ProtocolError(f"Leptrino {self.port!r}: no valid reply to {command.name} "
                            f"(0x{int(command):02X}) after {self.retries} attempts "
                            f"({last_problem})")

    def product_info(self) -> ProductInfo:
        return parse_product_info(self.request(Command.PRODUCT_INFO))

    def rated_values(self) -> np.ndarray:
        """Rated Fx, Fy, Fz (N) and Mx, My, Mz (N m) as stored in the sensor."""
        values = parse_rated_values(self.request(Command.RATED_VALUES))
        if not np.all(np.isfinite(values)) or np.any(values <= 0):
            raise ProtocolError(f"Leptrino {self.port!r} reported invalid rated values "
                                f"{values.tolist()}")
        return values

    def read_one(self) -> DataRecord:
        """One record by handshake (command 0x30); not used while streaming."""
        return parse_data_record(self.request(Command.HANDSHAKE))

    def start_continuous(self) -> None:
        """Command 0x32. Records start to arrive; the sensor sends no separate reply."""
        self._write(Command.START_CONTINUOUS)

    def stop_continuous(self) -> None:
        """Command 0x33, then drain until its reply (records still in flight are dropped)."""
        self.request(Command.STOP_CONTINUOUS)


class LeptrinoAcquisition:
    """:class:`~nmsid.drivers.interfaces.ForceAcquisition` over a Leptrino USB sensor."""

    def __init__(self, sensor: LeptrinoSensor, *,
                 extension_direction=(1.0, 0.0, 0.0), sync_on_external_input: bool = False):
        d = np.asarray(extension_direction, dtype=float)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
            raise ValueError("extension_direction must be 3 finite numbers, not all zero; "
                             f"got {extension_direction!r}")
        self.sensor = sensor
        self.direction = d / np.linalg.norm(d)
        self.sync_on_external_input = sync_on_external_input
        self.info: ProductInfo | None = None
        self.rated: np.ndarray | None = None
        self._rate_Hz = NOMINAL_RATE_HZ
        self._running = False
        self._armed_wait_sync = False
        self._index = 0
        self._remaining: int | None = None
        self._dead: str = ""

    # -- lifecycle ------------------------------------------------------------------
    def connect(self) -> ProductInfo:
        """Open the port, stop any stream left running, read product info and ratings."""
        self.sensor.open()
        try:
            self.sensor.stop_continuous()
        except ProtocolError:
            pass  # not streaming, or a sensor that does not ack 0x33 when idle
        self.info = self.sensor.product_info()
        self.rated = self.sensor.rated_values()
        if np.isfinite(self.info.output_rate_Hz) and self.info.output_rate_Hz > 0:
            self._rate_Hz = self.info.output_rate_Hz
        return self.info

    def configure(self, fs_Hz: float) -> float:
        if self.info is None:
            self.connect()
        if abs(fs_Hz - self._rate_Hz) > 1e-9:
            log.warning("Leptrino %s streams at %.0f Hz; %.0f Hz was asked, the real rate "
                        "is used", self.sensor.port, self._rate_Hz, fs_Hz)
        return self._rate_Hz

    @property
    def rate_Hz(self) -> float:
        return self._rate_Hz

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        if self.info is None:
            self.connect()
        self._index = 0
        self._remaining = n_samples
        self._dead = ""
        self._armed_wait_sync = bool(triggered and self.sync_on_external_input)
        if triggered and not self.sync_on_external_input:
            log.warning("Leptrino %s has no hardware trigger wired "
                        "(sync_on_external_input = false): onset alignment is host-timed",
                        self.sensor.port)
        self.sensor.start_continuous()
        self._running = True

    def read(self, timeout_s: float) -> ForceChunk | None:
        if self._dead:
            return self._fault_chunk(self._dead)
        if not self._running:
            return None
        deadline = time.monotonic() + timeout_s
        records: list[DataRecord] = []
        corrupt = 0
        other_fault = ""
        while not records and time.monotonic() < deadline:
            try:
                events = self.sensor.poll(max(0.0, min(0.02, deadline - time.monotonic())))
            except (OSError, ProtocolError) as exc:  # SerialException subclasses OSError
                self._dead = f"serial port error on {self.sensor.port!r}: {exc}"
                log.error("Leptrino %s", self._dead)
                return self._fault_chunk(self._dead)
            for ev in events:
                if isinstance(ev, Corrupt):
                    if ev.length >= DATA_RECORD_LEN - 4:
                        corrupt += 1  # a record-sized frame failed: a sample is lost
                elif isinstance(ev, Nak):
                    other_fault = "sensor sent NAK while streaming"
                elif isinstance(ev, Frame) and ev.command in (Command.START_CONTINUOUS,
                                                              Command.HANDSHAKE):
                    if ev.result != Result.OK:
                        other_fault = f"data frame with error result 0x{ev.result:02X}"
                        continue
                    if len(ev.payload) < 20:
                        continue  # a bare acknowledgement of 0x32
                    rec = parse_data_record(ev)
                    if self._armed_wait_sync:
                        if not rec.status & Status.EXTERNAL_INPUT:
                            continue
                        self._armed_wait_sync = False
                    records.append(rec)
        if not records and not corrupt and not other_fault:
            return None
        if self._remaining is not None:
            records = records[:self._remaining]
            self._remaining -= len(records)
        return self._chunk(records, corrupt, other_fault)

    def _chunk(self, records: list[DataRecord], corrupt: int, other_fault: str) -> ForceChunk:
        n = len(records)
        raw = np.array([r.raw for r in records], dtype=np.float64).reshape(n, 6)
        wrench = raw * (self.rated / RAW_AT_RATED)
        force = wrench[:, :3] @ self.direction
        status = 0
        for r in records:
            status |= int(r.status)
        details = []
        if corrupt:
            details.append(f"{corrupt} corrupt frame(s) dropped")
        if status & Status.OVER_RATED:
            details.append("load above the sensor's rated value")
        if status & (Status.SENSOR_FAULT | Status.ROM_ERROR):
            details.append("sensor reports a fault (status 0x%02X)" % status)
        if other_fault:
            details.append(other_fault)
        flags = AcquisitionFlags(
            overrun=corrupt > 0,
            over_range=bool(status & Status.OVER_RATED),
            sensor_fault=bool(status & (Status.SENSOR_FAULT | Status.ROM_ERROR))
            or bool(other_fault),
            detail="; ".join(details))
        chunk = ForceChunk(start_index=self._index, force_N=force, wrench=wrench,
                           flags=flags)
        self._index += n
        return chunk

    def _fault_chunk(self, detail: str) -> ForceChunk:
        return ForceChunk(start_index=self._index, force_N=np.zeros(0),
                          wrench=np.zeros((0, 6)),
                          flags=AcquisitionFlags(sensor_fault=True, detail=detail))

    def stop(self) -> None:
        if not self._running:
            return
        self._running = False
        if self._dead or not self.sensor.is_open:
            return
        try:
            self.sensor.stop_continuous()
        except (OSError, ProtocolError) as exc:
            log.warning("Leptrino %s: stop failed: %s", self.sensor.port, exc)

    def close(self) -> None:
        try:
            self.stop()
        finally:
            self.sensor.close()
