"""Hardware emergency-stop switch read by the host: a serial modem-status line or a DAQ input.

Wiring (fail-safe, see docs/hardware.md): a normally-closed mushroom switch closes a loop
from an output the host drives high to an input it reads:

* USB-serial adapter: RTS -> switch -> CTS (``line = "CTS"``), or DTR -> switch -> DSR
  (``line = "DSR"``). The driver asserts RTS / DTR; while the switch is released the input
  reads asserted. Pressing it opens the loop; so does a cut wire or an unplugged plug.
* NI DAQ digital input: a pulled-up line through the NC switch to ground, or a driven
  line; ``released_level`` says what it reads while the switch is released.

Whatever cannot be read (port gone, adapter unplugged, driver error) reads as pressed.
A lost serial port is reopened at most once a second; it reads released again only after
its line reads asserted again (the engine's interlock stays latched until re-armed anyway).
This switch is the host's stop; the paper's rig also cuts the stimulator's power with a
switch, which is independent of any software and should be kept.
"""

from __future__ import annotations

import logging
import threading
import time

from nmsid.drivers.errors import DeviceNotFound
from nmsid.drivers.leptrino import _serial_module, port_in_use
from nmsid.drivers.nidaq import load_nidaqmx

log = logging.getLogger(__name__)

LINES = {"CTS": "rts", "DSR": "dtr"}
"""Input line -> the output line that powers the loop."""


class SerialEStop:
    """E-stop on a USB-serial adapter's CTS or DSR line (pyserial).

    Parameters
    ----------
    port : str
        Serial port or pyserial URL.
    line : str
        ``CTS`` (loop from RTS) or ``DSR`` (loop from DTR).
    """

    def __init__(self, port: str, line: str = "CTS", *, reopen_interval_s: float = 1.0):
        if line not in LINES:
            raise ValueError(f"estop.line {line!r} is not one of {sorted(LINES)}")
        self.port = port
        self.line = line
        self.reopen_interval_s = reopen_interval_s
        self._ser = None
        self._lock = threading.Lock()
        self._last_reopen = 0.0
        self._reported = False

    def open(self) -> None:
        """Open the port and drive the loop's output line high.

        Raises
        ------
        DeviceNotFound
            If the port cannot be opened (names the port and the setting).
        """
        serial = _serial_module()
        try:
            ser = serial.serial_for_url(self.port, do_not_open=True)
            setattr(ser, LINES[self.line], True)
            ser.open()
            setattr(ser, LINES[self.line], True)
        except (serial.SerialException, OSError, ValueError) as exc:
            if port_in_use(exc):  # Windows: COM ports are exclusive (drivers.leptrino)
                raise DeviceNotFound(
                    f"the E-stop port {self.port!r} is in use by another program (Windows "
                    "opens a COM port for one program at a time: close the other program); "
                    "the adapter and cable are not the problem") from None
            raise DeviceNotFound(f"cannot open the E-stop port {self.port!r}: {exc}; check "
                                 "the USB-serial adapter and estop.port") from None
        self._ser = ser
        self._reported = False

    def is_pressed(self) -> bool:
        with self._lock:
            if self._ser is None:
                if time.monotonic() - self._last_reopen < self.reopen_interval_s:
                    return True
                self._last_reopen = time.monotonic()
                try:
                    self.open()
                except DeviceNotFound:
                    return True
            try:
                asserted = bool(getattr(self._ser, self.line.lower()))
            except Exception as exc:  # unreadable -> pressed (fail-safe)
                if not self._reported:
                    log.error("E-stop port %s unreadable (%s): reads as pressed", self.port, exc)
                    self._reported = True
                self._drop()
                return True
            return not asserted

    def _drop(self) -> None:
        ser, self._ser = self._ser, None
        self._last_reopen = time.monotonic()
        if ser is not None:
            try:
                ser.close()
            except Exception:
                pass

    def close(self) -> None:
        with self._lock:
            self._drop()

    def describe(self) -> dict:
        return {"port": self.port, "line": self.line,
                "pressed": self.is_pressed()}


class NidaqEStop:
    """E-stop on an NI DAQ digital input line (nidaqmx ``di_channels.add_di_chan``)."""

    def __init__(self, line: str, *, released_level: bool = True, api=None):
        self.line = line
        self.released_level = bool(released_level)
        self._api = api
        self._task = None
        self._lock = threading.Lock()

    def open(self) -> None:
        api = self._api or load_nidaqmx()
        try:
            task = api.nidaqmx.Task("nmsid-estop")
            task.di_channels.add_di_chan(self.line)
        except api.errors.DaqError as exc:
            raise DeviceNotFound(f"E-stop DAQ line {self.line!r}: {exc}; check estop.line")\
                from None
        self._task = task

    def is_pressed(self) -> bool:
        with self._lock:
            if self._task is None:
                return True
            try:
                return bool(self._task.read()) != self.released_level
            except Exception as exc:
                log.error("E-stop DAQ line %s unreadable (%s): reads as pressed", self.line, exc)
                return True

    def close(self) -> None:
        with self._lock:
            task, self._task = self._task, None
        if task is not None:
            try:
                task.close()
            except Exception:
                pass

    def describe(self) -> dict:
        return {"line": self.line, "pressed": self.is_pressed()}
