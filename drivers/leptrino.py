"""Leptrino 6-axis force sensor on its USB (virtual COM port) interface, via pyserial.

:class:`LeptrinoSensor` speaks the command protocol of :mod:`nmsid.drivers.leptrino_protocol`
(product information, rated values, start / stop continuous output) over a serial port;
:class:`LeptrinoAcquisition` wraps it as a :class:`nmsid.drivers.interfaces.ForceAcquisition`.

Rate: the sensor streams at its own fixed rate, which nothing in the protocol states
(specification v1.13, 5.1: product information has model, serial and firmware only; a
rate text some firmware adds is informative). :meth:`LeptrinoAcquisition.configure`
MEASURES the record rate (:meth:`~LeptrinoAcquisition.measure_rate`: records counted
against host time over :data:`RATE_MEASURE_S`, least-squares slope) and places record
``k`` at ``k / measured rate``; the force is then resampled (linear interpolation) onto the
session's grid ``n / fs_Hz``, so the session's time axis follows the measured rate and a
sensor streaming at 1000 Hz is not stamped as 1200 Hz.

The sensor's FIR digital filter (0xB6, 5.3: off, 10, 100 or 200 Hz; 100 Hz delays and
band-limits the force) is read at connect and reported (:meth:`describe`). A tare for
this chain: :meth:`LeptrinoAcquisition.tare` (mean of the unloaded records, subtracted).
Records at +-32000 (6: "a force above 3.2 times the rating is also +-32000") are clipped:
``over_range``.

Time base: the digital interface has no hardware start trigger, and no status bit is an
external input: specification v1.13, 6.1 defines bits 0-2 and marks bits 3-7 reserved
(undefined), so ``sync_on_external_input`` is refused (:data:`SYNC_ON_EXTERNAL_INPUT_REFUSED`)
rather than starting a trial on an undefined bit. A triggered start is aligned to the first
record after :meth:`start` (host timing: one record plus USB latency, logged as a
warning). Reserved status bits are masked off by the protocol layer and never raise a
flag.

A USB glitch: :meth:`reconnect`
closes the dead port handle and opens the port anew (never reusing the old handle), then
reads product information and rated values again.

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
from collections.abc import Callable

import numpy as np

from nmsid.drivers.errors import (
    DeviceError,
    DeviceNotFound,
    HardwareConfigError,
    ProtocolError,
    VendorLibraryMissing,
)
from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk
from nmsid.drivers.leptrino_protocol import (
    DATA_RECORD_LEN,
    FULL_SCALE_RAW,
    RAW_AT_RATED,
    Command,
    Corrupt,
    DataRecord,
    FilterSetting,
    Frame,
    FrameDecoder,
    Nak,
    ProductInfo,
    Result,
    Status,
    encode_command,
    parse_data_record,
    parse_filter,
    parse_product_info,
    parse_rated_values,
)
from nmsid.protocols import os_platform

log = logging.getLogger(__name__)

DEFAULT_BAUD = 460800
NOMINAL_RATE_HZ = 1200.0
"""Leptrino's sample as shipped in the ROS driver says "maximum 1.2 kHz"; only a plausibility
reference now: the rate used is measured."""
RATE_MEASURE_S = 1.0
"""How long :meth:`LeptrinoAcquisition.measure_rate` counts records by default."""
MIN_RATE_RECORDS = 50
"""Fewer records than this in the measurement: the sensor is not streaming properly."""


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
        raise port_open_error(port, exc, "the Leptrino sensor",
                              "acquisition.leptrino.port") from None


def port_in_use(exc: BaseException) -> bool:
    """True if opening a port failed because another program holds it.

    Windows opens a COM port exclusively (``CreateFile`` with share mode 0, Microsoft's
    "Communications Resources" documentation): a second open fails with ERROR_ACCESS_DENIED
    (5), which pyserial reports as ``could not open port 'COM5': PermissionError(13,
    'Access is denied.', None, 5)``. Asked only on Windows (:mod:`nmsid.protocols.os_platform`).
    """
    if not os_platform.is_windows():
        return False
    text = str(exc)
    return (isinstance(exc, PermissionError) or "Access is denied" in text
            or "PermissionError" in text or "WinError 5" in text)


def port_open_error(port: str, exc: BaseException, device: str, setting: str) -> DeviceNotFound:
    """One line for a port that did not open: in use by another program, or not there."""
    if port_in_use(exc):
        return DeviceNotFound(
            f"serial port {port!r} for {device} is in use by another program (Windows opens "
            "a COM port for one program at a time: close the vendor's tool, a terminal "
            "program or another nmsid); the cable is not the problem")
    return DeviceNotFound(f"cannot open serial port {port!r} for {device}: {exc}. Check the "
                          f"USB cable and the port name ({setting})")


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
        self.start_naks = 0

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

    @property
    def device(self) -> str:
        return f"Leptrino on {self.port!r}"

    def product_info(self) -> ProductInfo:
        return parse_product_info(self.request(Command.PRODUCT_INFO), self.device)

    def rated_values(self) -> np.ndarray:
        """Rated Fx, Fy, Fz (N) and Mx, My, Mz (N m) as stored in the sensor."""
        values = parse_rated_values(self.request(Command.RATED_VALUES), self.device)
        if not np.all(np.isfinite(values)) or np.any(values <= 0):
            raise ProtocolError(f"Leptrino {self.port!r} reported invalid rated values "
                                f"{values.tolist()}")
        return values

    def read_one(self) -> DataRecord:
        """One record by handshake (command 0x30); not used while streaming."""
        return parse_data_record(self.request(Command.HANDSHAKE), self.device)

    def filter_setting(self) -> FilterSetting:
        """The FIR digital filter (0xB6, specification v1.13 5.3)."""
        return parse_filter(self.request(Command.FILTER), self.device)

    def start_continuous(self) -> None:
        """Command 0x32, confirmed: specification v1.13 6.2, "the sensor sends the response
        to this command, then sends data"; a ``DLE NAK`` means "the host must resend the
        command" (2.4.3). Records that arrive with or before the response are kept for
        :meth:`poll`. A sensor that streams without the response is accepted (logged).

        Raises
        ------
        ProtocolError
            No response and no records after ``retries`` attempts, or an error result.
        """
        last_problem = "no reply"
        for _attempt in range(self.retries):
            self._write(Command.START_CONTINUOUS)
            deadline = time.monotonic() + self.reply_timeout_s
            keep: list = []
            nak = False
            while time.monotonic() < deadline and not nak:
                for ev in self.poll(min(0.02, max(deadline - time.monotonic(), 0))):
                    if isinstance(ev, Nak):
                        nak, last_problem = True, "NAK (sensor rejected the frame)"
                        self.start_naks += 1
                    elif isinstance(ev, Frame) and ev.command == Command.START_CONTINUOUS:
                        if ev.result != Result.OK:
                            raise ProtocolError(
                                f"Leptrino {self.port!r} answered START_CONTINUOUS (0x32) "
                                f"with error result 0x{ev.result:02X}")
                        if len(ev.payload) < DATA_RECORD_LEN:
                            self._pending = keep + self._pending
                            return           # the acknowledgement (LEN 4)
                        keep.append(ev)      # a record: streaming without the response
                    else:
                        keep.append(ev)
                if keep and any(isinstance(e, Frame) for e in keep) and not nak:
                    log.warning("Leptrino %s streams without acknowledging 0x32",
                                self.port)
                    self._pending = keep + self._pending
                    return
            log.warning("Leptrino %s: %s to START_CONTINUOUS, resending", self.port,
                        last_problem)
        raise ProtocolError(f"Leptrino {self.port!r}: START_CONTINUOUS (0x32) not "
                            f"acknowledged after {self.retries} attempts ({last_problem})")

    def stop_continuous(self) -> None:
        """Command 0x33, then drain until its reply (records still in flight are dropped)."""
        self.request(Command.STOP_CONTINUOUS)


def fit_record_rate(t_s: np.ndarray, counts: np.ndarray, rounds: int = 3) -> float:
    """Records per second from (arrival time, cumulative count) pairs.

    USB and host-scheduling delays only ever make a batch arrive LATE, so the points that
    arrived earliest for their count lie closest to the true line: a least-squares fit,
    then ``rounds`` refits on the half of the points that arrived earliest relative to the
    previous line (the lower envelope of the delays).
    """
    keep = np.ones(len(t_s), dtype=bool)
    slope, icpt = np.polyfit(t_s, counts, 1)
    for _ in range(rounds):
        resid = counts - (slope * t_s + icpt)      # early arrival = more records than the line
        cut = np.median(resid[keep])
        new = keep & (resid >= cut)
        if new.sum() < 3:
            break
        keep = new
        slope, icpt = np.polyfit(t_s[keep], counts[keep], 1)
    return float(slope)


SYNC_ON_EXTERNAL_INPUT_REFUSED = (
    "acquisition.leptrino.sync_on_external_input = true: the Leptrino specification v1.13, "
    "6.1 defines no external-input bit (status bits 3-7 are reserved and undefined), so a "
    "trial cannot start on it; set it to false (onset aligned by host timing) or record the "
    "force through an A/D with the stimulator's sync (acquisition.kind = \"caio\" or "
    "\"nidaq\")")
"""Why ``sync_on_external_input`` is refused (issue 37 item 6)."""


class LeptrinoAcquisition:
    """:class:`~nmsid.drivers.interfaces.ForceAcquisition` over a Leptrino USB sensor."""

    def __init__(self, sensor: LeptrinoSensor, *,
                 extension_direction=(1.0, 0.0, 0.0), sync_on_external_input: bool = False):
        d = np.asarray(extension_direction, dtype=float)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
            raise HardwareConfigError("extension_direction must be 3 finite numbers, not all "
                                      f"zero; got {extension_direction!r}")
        if sync_on_external_input:
            raise HardwareConfigError(SYNC_ON_EXTERNAL_INPUT_REFUSED)
        self.sensor = sensor
        self.direction = d / np.linalg.norm(d)
        self.info: ProductInfo | None = None
        self.rated: np.ndarray | None = None
        self.filter: FilterSetting | None = None
        self.measured_rate_Hz: float | None = None
        self.offset = np.zeros(6)
        """Tare (:meth:`tare`): subtracted from every wrench (N, N m)."""
        self._rate_Hz = NOMINAL_RATE_HZ
        self._fs_out = 0.0
        self._n_rec = 0
        self._last: tuple[float, np.ndarray] | None = None
        self._running = False
        self._index = 0
        self._remaining: int | None = None
        self._dead: str = ""

    def _rated_values(self) -> np.ndarray:
        """The rated values read at :meth:`connect` (DeviceError before it)."""
        if self.rated is None:
            raise DeviceError(f"Leptrino {self.sensor.port!r}: not connected (its rated "
                              "values are unknown); call connect() first")
        return self.rated

    # -- lifecycle ------------------------------------------------------------------
    def connect(self) -> ProductInfo:
        """Open the port, stop any stream left running, read product info and ratings."""
        self.sensor.open()
        try:
            self.sensor.stop_continuous()
        except ProtocolError:
            pass  # not streaming, or a sensor that does not ack 0x33 when idle
        info = self.sensor.product_info()
        self.rated = self.sensor.rated_values()
        try:
            self.filter = self.sensor.filter_setting()
            log.info("Leptrino %s: digital filter %s", self.sensor.port,
                     self.filter.describe())
        except ProtocolError as exc:  # a model without 0xB6: said, not fatal
            self.filter = None
            log.warning("Leptrino %s: digital filter not readable (%s)", self.sensor.port,
                        exc)
        self.measured_rate_Hz = None
        self.info = info
        return info

    def reconnect(self, fs_Hz: float | None = None) -> float:
        """After a USB glitch: close the (dead) port, open it anew, read the sensor again.

        The old handle is never reused: :meth:`LeptrinoSensor.close` drops it and
        :meth:`LeptrinoSensor.open` asks the serial factory for a new one.

        Returns
        -------
        float
            The rate the sensor streams at.

        Raises
        ------
        DeviceNotFound, ProtocolError
            If the port cannot be opened or the sensor does not answer.
        """
        self.close()
        self.connect()
        return self.configure(fs_Hz if fs_Hz is not None else self._rate_Hz)

    def device_fault(self) -> str:
        """Between trials: "" if the sensor answers, else what is wrong (for the engine).

        Asks for the product information (one short command; the stream is stopped
        between trials), so a port that died while idle is found before the next trial.
        """
        if self._dead:
            return self._dead
        if self._running:
            return ""
        if not self.sensor.is_open:
            return f"serial port {self.sensor.port!r} is not open"
        try:
            self.sensor.product_info()
        except (OSError, ProtocolError) as exc:
            return f"no answer on {self.sensor.port!r}: {exc}"
        return ""

    def configure(self, fs_Hz: float) -> float:
        """Measure the record rate (once per connection) and deliver ``fs_Hz``.

        The records are placed at ``k / measured rate`` and resampled onto ``n / fs_Hz``;
        ``fs_Hz`` well above the measured rate is allowed but warned about (no information
        is added by interpolation).
        """
        if self.info is None:
            self.connect()
        if not fs_Hz > 0:
            raise HardwareConfigError(f"acquisition rate must be positive, got {fs_Hz!r}")
        if self.measured_rate_Hz is None:
            self.measure_rate()
        self._fs_out = float(fs_Hz)
        if fs_Hz > 1.05 * self._rate_Hz:
            log.warning("Leptrino %s streams at %.1f Hz (measured); %.0f Hz is asked: the "
                        "force is interpolated, no faster than the sensor", self.sensor.port,
                        self._rate_Hz, fs_Hz)
        return self._fs_out

    def measure_rate(self, seconds: float | None = None) -> float:
        """Stream for ``seconds`` (default :data:`RATE_MEASURE_S`) and measure the record
        rate (Hz).

        The cumulative record count is regressed on the host time at which each batch
        arrived (least squares), so USB latency jitter averages out; the first batch is
        the time origin. The stated rate, if any, is compared and a difference logged.

        Raises
        ------
        ProtocolError
            Fewer than :data:`MIN_RATE_RECORDS` records arrived.
        """
        if seconds is None:
            seconds = RATE_MEASURE_S
        self.sensor.start_continuous()
        t0 = time.monotonic()
        times, counts, n = [], [], 0
        try:
            while time.monotonic() - t0 < seconds:
                events = self.sensor.poll(0.02)
                got = sum(1 for ev in events if isinstance(ev, Frame)
                          and ev.command == Command.START_CONTINUOUS
                          and len(ev.payload) >= DATA_RECORD_LEN)
                if got:
                    n += got
                    times.append(time.monotonic())
                    counts.append(n)
        finally:
            self.sensor.stop_continuous()
        if n < MIN_RATE_RECORDS or len(times) < 3:
            raise ProtocolError(f"Leptrino {self.sensor.port!r}: only {n} records in "
                                f"{seconds:g} s while streaming; the sensor is not "
                                "streaming properly")
        slope = fit_record_rate(np.asarray(times) - times[0], np.asarray(counts, float))
        self.measured_rate_Hz = self._rate_Hz = slope
        info = self.info
        if info is not None and info.rate_stated and abs(slope / info.output_rate_Hz - 1) > 0.02:
            log.warning("Leptrino %s states %g Hz but streams at %.1f Hz (measured); the "
                        "measured rate is used", self.sensor.port, info.output_rate_Hz, slope)
        log.info("Leptrino %s: record rate %.2f Hz (measured over %d records)",
                 self.sensor.port, slope, n)
        return slope

    def tare(self, seconds: float = 0.5) -> np.ndarray:
        """Zero the USB chain: the mean wrench of ``seconds`` of unloaded records becomes the
        offset subtracted from every later wrench. Call with the arm off the sensor.

        Returns
        -------
        numpy.ndarray
            The offset (Fx, Fy, Fz in N, Mx, My, Mz in N m).
        """
        if self.info is None:
            self.connect()
        self.sensor.start_continuous()
        t0 = time.monotonic()
        raws = []
        try:
            while time.monotonic() - t0 < seconds:
                for ev in self.sensor.poll(0.02):
                    if isinstance(ev, Frame) and ev.command == Command.START_CONTINUOUS \
                            and len(ev.payload) >= DATA_RECORD_LEN:
                        raws.append(parse_data_record(ev, self.sensor.device).raw)
        finally:
            self.sensor.stop_continuous()
        if not raws:
            raise ProtocolError(f"Leptrino {self.sensor.port!r}: no records for the tare")
        self.offset = np.mean(np.asarray(raws, dtype=float), axis=0) * (self._rated_values()
                                                                       / RAW_AT_RATED)
        log.info("Leptrino %s: tare %s from %d records", self.sensor.port,
                 np.round(self.offset, 4).tolist(), len(raws))
        return self.offset.copy()

    def describe(self) -> dict:
        """What ``nmsid probe`` prints."""
        info = self.info
        return {"record_rate_Hz (measured)": (round(self.measured_rate_Hz, 2)
                                              if self.measured_rate_Hz else "not measured"),
                "rate stated by the sensor": (f"{info.output_rate_Hz:g} Hz ({info.rate_text})"
                                              if info is not None and info.rate_stated
                                              else "none (specification 5.1 has no rate)"),
                "digital filter": self.filter.describe() if self.filter else "unknown",
                "tare_N": np.round(self.offset[:3], 4).tolist()}

    @property
    def rate_Hz(self) -> float:
        return self._rate_Hz

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        if self.info is None:
            self.connect()
        self._index = 0
        self._n_rec = 0
        self._last = None
        if not self._fs_out:
            self._fs_out = self._rate_Hz
        self._remaining = n_samples
        self._dead = ""
        if triggered:
            log.warning("Leptrino %s has no hardware trigger (specification 6.1 defines "
                        "no external input): onset alignment is host-timed",
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
                    records.append(parse_data_record(ev, self.sensor.device))
        if not records and not corrupt and not other_fault:
            return None
        return self._chunk(records, corrupt, other_fault)

    def _resample(self, wrench: np.ndarray) -> np.ndarray:
        """Records at ``k / measured rate`` -> samples at ``n / fs``, linear interpolation;
        keeps the last record for the next chunk. Returns the new samples (n, 6)."""
        m = len(wrench)
        k = self._n_rec + np.arange(m)
        t_rec = k / self._rate_Hz
        self._n_rec += m
        if self._last is not None:
            t_rec = np.concatenate(([self._last[0]], t_rec))
            wrench = np.vstack([self._last[1][None, :], wrench])
        self._last = (float(t_rec[-1]), wrench[-1].copy())
        n_end = int(np.floor(t_rec[-1] * self._fs_out + 1e-9)) + 1
        if self._remaining is not None:
            n_end = min(n_end, self._index + self._remaining)
        n = np.arange(self._index, max(n_end, self._index))
        t_out = n / self._fs_out
        out = np.empty((len(n), 6))
        for j in range(6):
            out[:, j] = np.interp(t_out, t_rec, wrench[:, j])
        return out

    def _chunk(self, records: list[DataRecord], corrupt: int, other_fault: str) -> ForceChunk:
        raw = np.array([r.raw for r in records], dtype=np.float64).reshape(len(records), 6)
        clipped = bool(np.any(np.abs(raw) >= FULL_SCALE_RAW))
        wrench = self._resample(raw * (self._rated_values() / RAW_AT_RATED)) - self.offset
        n = len(wrench)
        if self._remaining is not None:
            self._remaining -= n
        force = wrench[:, :3] @ self.direction
        status = 0
        for r in records:
            status |= int(r.status)
        details = []
        if corrupt:
            details.append(f"{corrupt} corrupt frame(s) dropped")
        if clipped:
            details.append(f"sensor output clipped at +-{FULL_SCALE_RAW} (above 3.2 x rated)")
        if status & Status.OVER_RATED:
            details.append("load above the sensor's rated value")
        if status & (Status.SENSOR_FAULT | Status.ROM_ERROR):
            details.append(f"sensor reports a fault (status 0x{int(status):02X})")
        if other_fault:
            details.append(other_fault)
        flags = AcquisitionFlags(
            overrun=corrupt > 0,
            over_range=bool(status & Status.OVER_RATED) or clipped,
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
            self.info = None  # the next configure()/start() opens the port and reads anew
