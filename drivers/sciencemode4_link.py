"""The ScienceMode4 packet link of :class:`~nmsid.drivers.sciencemode4.Sm4Stimulator`:
the reader thread, requests and their replies (resent when lost or corrupted), the
confirmed stop and its fallback (a mixin; its state is set by the stimulator's
``__init__``). Sources as in :mod:`nmsid.drivers.sciencemode4_protocol`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from nmsid.drivers import sciencemode4_protocol as sm4
from nmsid.drivers.errors import DeviceError
from nmsid.drivers.interfaces import StimulatorState

log = logging.getLogger("nmsid.drivers.sciencemode4")

RESPONSE_WAIT_S = 0.1
"""A request unanswered this long is sent again (the P24 answers in 5-15 ms, issue 43; x 6
for a host thread scheduled late). A reply with a bad checksum is resent at once."""
REQUEST_TRIES = 3
STOP_CONFIRM_S = 1.0
"""How long the stop is resent and Get_stim_status asked before the fallback."""


class Sm4Link:
    """The packet layer (see the module docstring)."""

    model: Any
    clock: Callable[[], float]
    _ser: Any
    _decoder: sm4.Decoder
    _wlock: threading.Lock
    _lock: threading.RLock
    _cv: threading.Condition
    _number: int
    _replies: dict[int, sm4.Packet | sm4.BadPacket]
    _pulse_acks: dict[int, tuple[int, tuple[int, ...]]]
    _late_acks: dict[int, tuple[int, tuple[int, ...]]]
    _unanswered: set[int]
    _update_ack: int
    _silent: bool
    _error: str
    _state: StimulatorState
    _link: threading.Thread | None
    _link_stop: threading.Event
    _stream_stop: threading.Event
    _delivered: dict[int, set[int]]
    _counts: dict[str, int]
    stop_log: list[tuple[float, str]]
    _confirm_stopped: Callable[..., bool]
    _link_failed: Callable[..., None]
    _wait_for: Callable[..., Any]

    def _link_loop(self) -> None:
        while not self._link_stop.is_set():
            try:
                ser = self._ser
                n = ser.in_waiting if ser is not None else 0
                packets = self._decoder.feed(ser.read(n)) if n else []
            except Exception as exc:
                self._link_failed(exc)
                return
            for pkt in packets:
                self._on_packet(pkt)
            time.sleep(0.001)

    def _on_packet(self, pkt: sm4.Packet | sm4.BadPacket) -> None:
        with self._lock:
            late = pkt.command == self._update_ack and pkt.number in self._late_acks
            if pkt.command == self._update_ack and (pkt.number in self._pulse_acks or late):
                index, chans = (self._late_acks if late else self._pulse_acks).pop(pkt.number)
                if late:      # answered after its slot: not lost (the device answers a
                    self._counts["updates_answered_late"] += 1   # pulse after it)
                    if all(i != index for i, _ in self._late_acks.values()):
                        self._unanswered.discard(index)
                ch = chans[0]
                result = pkt.result if isinstance(pkt, sm4.Packet) else sm4.TRANSFER_ERROR
                if result == sm4.OK:
                    self._delivered.setdefault(index, set()).update(chans)
                elif result == sm4.TRANSFER_ERROR:     # IFU Table 27 01: not executed;
                    self._counts["updates_transfer_error"] += 1   # the next one follows
                elif result == sm4.NOT_INITIALIZED and self._stream_stop.is_set():
                    pass                               # crossed the stop: not executed
                else:
                    text = sm4.RESULT_TEXT.get(result, f"code {result}")
                    self._error = self._error or (f"{self.model.title} channel {ch}: {text} "
                                                  "(IFU Table 27); stimulation stopped")
                    self._state = StimulatorState.ERROR
            else:
                self._replies[pkt.number] = pkt
            self._cv.notify_all()

    def _ask(self, command: int, data: bytes = b"") -> sm4.Packet | sm4.BadPacket | None:
        """One request and its reply (None after :data:`RESPONSE_WAIT_S`)."""
        with self._wlock:
            number = self._write_locked(command, data)
        return self._wait_for(self._replies, number, time.monotonic() + RESPONSE_WAIT_S,
                              self._cv, 0.002)

    def _request(self, command: int, data: bytes = b"") -> sm4.Packet:
        """A request answered, resent when lost or answered corrupted (at once, never a 5 s
        timeout) or with a transfer error, up to :data:`REQUEST_TRIES` times."""
        for _ in range(REQUEST_TRIES):
            reply = self._ask(command, data)
            if isinstance(reply, sm4.Packet) and reply.command == sm4.UNKNOWN_CMD:
                raise DeviceError(f"{self.model.title} does not know command {command} "
                                  "(IFU Table 10)")
            if isinstance(reply, sm4.Packet) and reply.result != sm4.TRANSFER_ERROR:
                return reply
        raise DeviceError(f"{self.model.title}: no valid answer to command {command} in "
                          f"{REQUEST_TRIES} tries of {RESPONSE_WAIT_S:g} s")

    def _confirm_stop(self, level: int, resend: bool = True) -> bool:
        """Get_stim_status until "no level" (IFU Table 7), resending the stop of ``level``
        while it is not; unconfirmed: silent, one line (module docstring)."""
        stop = sm4.ML_STOP if level in (sm4.STIM_ML, sm4.STIM_ML_RUNNING) else sm4.LL_STOP

        def stopped() -> bool:
            reply = self._ask(sm4.GET_STIM_STATUS)
            return isinstance(reply, sm4.Packet) and reply.result == sm4.OK and \
                len(reply.data) > 1 and reply.data[1] == sm4.STIM_NONE
        return self._confirm_stopped(stopped, lambda: self._ask(stop), resend_first=resend,
                                     source="Get_stim_status, IFU Table 7")

    def _write_locked(self, command: int, data: bytes = b"") -> int:
        """Write one packet (the caller holds ``_wlock``); its packet number."""
        ser = self._ser
        if ser is None:
            raise DeviceError(f"{self.model.title} is not connected")
        if self._silent:
            raise DeviceError(self._error or f"{self.model.title} is silent after an "
                              "unconfirmed stop")
        number = self._number
        self._number = (self._number + 1) & 0x3F        # IFU: packet number 0 .. 63
        with self._lock:
            self._replies.pop(number, None)
            self._late_acks.pop(number, None)     # its number reused: unanswered for good
        ser.write(sm4.encode(number, command, data))
        return number
