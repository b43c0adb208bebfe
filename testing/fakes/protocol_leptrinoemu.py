"""pyserial URL handler ``leptrinoemu://<name>``: the in-process Leptrino emulator's port.

pyserial's ``serial_for_url`` imports ``<package>.protocol_<scheme>`` for each package in
``serial.protocol_handler_packages`` and uses its ``Serial`` class (pyserial's own
``loop://`` handler is built the same way); :func:`register` adds this package. Used on
Windows, where the emulator has no pseudo-terminal (see ``leptrino_emulator.py``).

Like a USB virtual COM port: reads wait up to ``timeout``; after the emulator is unplugged
every read and write raises ``SerialException`` ("the device reports readiness to read but
returned no data", as pyserial says for a vanished port), and a handle opened before a
replug stays dead.
"""

from __future__ import annotations

import time

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

_PACKAGE = "nmsid.testing.fakes"


def register() -> None:
    """Make ``serial_for_url("leptrinoemu://...")`` find this handler (idempotent)."""
    if _PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(_PACKAGE)


class Serial(SerialBase):
    """A pyserial port connected to one in-process emulator transport."""

    is_open: bool                       # SerialBase's (set in its __init__)

    def open(self):
        from nmsid.testing.fakes.leptrino_emulator import inprocess_transport  # noqa: PLC0415
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        name = str(self._port).split("://", 1)[-1]
        try:
            self._t = inprocess_transport(name)
        except OSError as exc:
            raise SerialException(str(exc)) from None
        self.is_open = True

    def close(self):
        self.is_open = False

    def _reconfigure_port(self):  # pyserial API: nothing to configure in process
        pass

    def _live(self):
        if not self.is_open:
            raise PortNotOpenError()
        if self._t.closed:
            raise SerialException("device reports readiness to read but returned no data "
                                  "(device disconnected?)")
        return self._t

    @property
    def in_waiting(self):
        t = self._live()
        with t.cond:
            return len(t.to_host)

    def read(self, size=1):
        t = self._live()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with t.cond:
            while len(t.to_host) < size and not t.closed:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    break
                t.cond.wait(left if left is not None else 0.05)
            if t.closed:
                raise SerialException("device disconnected")
            data = bytes(t.to_host[:size])
            del t.to_host[:size]
            return data

    def write(self, data):
        t = self._live()
        with t.cond:
            t.to_sensor += bytes(data)
            t.cond.notify_all()
        return len(data)

    def flush(self):
        self._live()

    def reset_input_buffer(self):
        t = self._live()
        with t.cond:
            t.to_host.clear()

    def reset_output_buffer(self):
        self._live()
