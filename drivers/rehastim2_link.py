"""The RehaStim2's ScienceMode2 link: packets out and in, acknowledgements, the keep-alive,
and the confirmed stop (a mixin of :class:`~nmsid.drivers.rehastim2.Rehastim2Stimulator`).

Sources, cited beside each behaviour: ScienceMode2 description v1.24 (*SM2*), sections
2.3 (MaxResponseTime, WatchdogTimeout), 4.1 (Init, Watchdog), 4.3 (StimulationError, the
-1 transfer error in an acknowledgement), 5.1 (result codes), 5.2 (the device's watchdog
reset), 5.3 (wait for the response, check the mode, resend).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from nmsid.drivers import rehastim2_protocol as sm2
from nmsid.drivers.errors import DeviceError
from nmsid.drivers.interfaces import StimulatorState
from nmsid.drivers.leptrino import _serial_module

log = logging.getLogger("nmsid.drivers.rehastim2")

KEEPALIVE_S = 0.4
"""Send the Watchdog after this long without a packet (SM2 2.3: WatchdogTimeout 1.2 s)."""
STOP_CONFIRM_S = 0.8
"""How long :meth:`Rehastim2Stimulator.stop_now` resends StopChannelListMode and asks
GetStimulationMode until the device answers mode 0 (SM2 5.3); then it withholds the
keep-alive (SM2 5.2: the device stops within its 1.2 s WatchdogTimeout)."""


class Sm2Link:
    """The packet layer; the state it uses is set by the stimulator's ``__init__``."""

    clock: Callable[[], float]
    _ser: Any
    _decoder: sm2.Decoder
    _wlock: threading.Lock
    _lock: threading.RLock
    _ack_cv: threading.Condition
    _number: int
    _last_sent: float
    _acks: dict[int, sm2.Packet]
    _waiting: set[int]
    _silent: bool
    _error: str
    _state: StimulatorState
    _link: threading.Thread | None
    _link_stop: threading.Event
    _update_numbers: dict[int, int]
    _pending_update: tuple[int, float] | None
    _delivered: list[int]
    _busy: int
    _transfer_errors: int
    _ack_errors: list[str]
    _onset_ack_s: float | None
    _t_start_call: float
    _confirm_stopped: Callable[..., bool]
    _link_failed: Callable[..., None]
    _wait_for: Callable[..., Any]

    def _confirm_stop(self) -> bool:
        """Ask GetStimulationMode until it answers 0, resending StopChannelListMode while it
        does not (SM2 5.3); unconfirmed: silent, so the device's watchdog acts (SM2 5.2).
        True if confirmed."""
        def stopped() -> bool:
            ack = self._ask(sm2.GET_STIM_MODE)
            return ack is not None and ack.result == 0 and len(ack.data) > 1 \
                and ack.data[1] == 0
        # the resent stop's answer (0, or -1: SM2 4.3) is checked by the mode that follows
        return self._confirm_stopped(stopped, lambda: self._ask(sm2.STOP_CLM),
                                     resend_first=False,
                                     source="GetStimulationMode, ScienceMode2 5.3")

    def _link_loop(self) -> None:
        while not self._link_stop.is_set():
            try:
                for pkt in self._read_packets():
                    self._on_packet(pkt)
                if self.clock() - self._last_sent > KEEPALIVE_S and not self._silent:
                    self._write(sm2.WATCHDOG)     # SM2 4.1 Watchdog, 2.3 WatchdogTimeout
            except Exception as exc:
                self._link_failed(exc)
                return
            time.sleep(0.002)

    def _on_packet(self, pkt: sm2.Packet) -> None:
        with self._lock:
            if pkt.command == sm2.STIMULATION_ERROR:          # SM2 4.3
                text = sm2.STIM_ERROR_TEXT.get(pkt.result, f"code {pkt.result}")
                self._error = f"RehaStim2 stimulation error: {text} (ScienceMode2 4.3)"
                self._state = StimulatorState.ERROR
            elif pkt.command == sm2.INIT:    # SM2 5.2: the device reset (watchdog expired)
                self._error = self._error or ("RehaStim2 reset its connection (watchdog "
                                              "expired, ScienceMode2 5.2)")
                self._state = StimulatorState.ERROR
            elif pkt.command == sm2.START_CLM_ACK:
                self._on_update_ack(pkt)
            elif pkt.number in self._waiting:  # a response someone waits for
                self._acks[pkt.number] = pkt
            self._ack_cv.notify_all()

    def _on_update_ack(self, pkt: sm2.Packet) -> None:
        """One StartChannelListMode response (called with the lock held)."""
        index = self._update_numbers.pop(pkt.number, None)
        if self._pending_update is not None and self._pending_update[0] == pkt.number:
            self._pending_update = None
        if pkt.result == 0:
            if index is not None:
                self._delivered.append(index)
            if self._onset_ack_s is None:
                self._onset_ack_s = time.monotonic() - self._t_start_call
        elif pkt.result == sm2.BUSY:         # SM2 5.1: not applied; SM2 1.3: may be skipped
            self._busy += 1
        elif pkt.result == sm2.TRANSFER_ERROR:   # SM2 4.3, 5.2: not executed; the next
            self._transfer_errors += 1           # update replaces it
        elif pkt.result == sm2.WRONG_MODE and self._state is not StimulatorState.RUNNING:
            log.debug("RehaStim2: an update that crossed the stop was refused (wrong mode, "
                      "SM2 Figure 4): the device is stopped, as asked")
        else:
            text = sm2.RESULT_TEXT.get(pkt.result, str(pkt.result))
            self._ack_errors.append(text)
            self._error = self._error or (f"RehaStim2 refused an update: {text} "
                                          "(ScienceMode2 5.1)")
            self._state = StimulatorState.ERROR

    def _ask(self, command: int, data: bytes = b"",
             timeout_s: float = sm2.MAX_RESPONSE_S * 2) -> sm2.Packet | None:
        """Send a command and return its response, or None after ``timeout_s`` (SM2 2.3
        MaxResponseTime, x 2 for a late host thread), whatever the driver's error state."""
        with self._wlock:
            number = self._number
            self._waiting.add(number)
        try:
            self._write(command, data, number=number)
            return self._wait_for(self._acks, number, time.monotonic() + timeout_s,
                                  self._ack_cv, 0.005)
        finally:
            with self._lock:
                self._waiting.discard(number)

    def _request(self, command: int, data: bytes = b"") -> sm2.Packet:
        """Send a command and wait for its response (SM2 2.3 MaxResponseTime, 5.3: one
        resend)."""
        for _ in range(2):                   # the request, then one resend
            with self._wlock:
                number = self._number
                self._waiting.add(number)
            self._write(command, data, number=number)
            deadline = time.monotonic() + 10 * sm2.MAX_RESPONSE_S
            with self._lock:
                while number not in self._acks and not self._error and \
                        time.monotonic() < deadline:
                    self._ack_cv.wait(0.01)
                ack = self._acks.pop(number, None)
                self._waiting.discard(number)
                if self._error and ack is None:
                    raise DeviceError(self._error)
            if ack is None:
                continue
            if ack.command == sm2.UNKNOWN_COMMAND:
                raise DeviceError(f"RehaStim2 does not know command {command} "
                                  "(ScienceMode2 5.2)")
            if ack.result != 0:
                raise DeviceError(f"RehaStim2 refused command {command}: "
                                  f"{sm2.RESULT_TEXT.get(ack.result, ack.result)} "
                                  "(ScienceMode2 5.1)")
            return ack
        raise DeviceError(f"RehaStim2: no response to command {command} within "
                          f"{10 * sm2.MAX_RESPONSE_S:g} s, twice (ScienceMode2 2.3)")

    def _write(self, command: int, data: bytes = b"", number: int | None = None) -> int:
        ser = self._ser
        if ser is None:
            raise DeviceError("RehaStim2 is not connected")
        if self._silent:
            raise DeviceError(self._error or "RehaStim2 is silent after an unconfirmed stop")
        with self._wlock:
            if number is None or number == self._number:
                number = self._number
                self._number = (self._number + 1) & 0xFF
            ser.write(sm2.encode(number, command, data))
            self._last_sent = self.clock()
        return number

    def _read_packets(self) -> list[sm2.Packet]:
        ser = self._ser
        if ser is None:
            return []
        n = ser.in_waiting
        return self._decoder.feed(ser.read(n)) if n else []


def _open_serial(port: str):
    """pyserial at the settings of SM2 Table 4 (460800 baud, 8 data bits, even parity,
    1 stop bit, no flow control)."""
    serial = _serial_module()
    return serial.Serial(port, baudrate=sm2.BAUDRATE, bytesize=8, parity="E", stopbits=1,
                         timeout=0.02, write_timeout=0.5, rtscts=False)
