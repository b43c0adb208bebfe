"""A fake Hasomed RehaStim2 at the serial byte level, written from the ScienceMode2 description.

Source: Hasomed, "ScienceMode2 - RehaStim2 Stimulation Device, Description and Protocol",
version 1.24, 2012-12-12 (``ScienceMode/ScienceMode2``; *SM2* below, with its section).
Each behaviour below cites the section it comes from. The fake is a serial port object
(``write``, ``read``, ``in_waiting``, ``close``, ``reset_input_buffer``, like pyserial's),
so the driver's own bytes are parsed here exactly as the device would receive them; time
runs on a clock (the fake bench's in fake mode), never on the driver's assumptions.

Faults of the link it models (tests inject them): packets lost on the line (no answer, no
watchdog fed: SM2 5.2 "data transfer physically broken / disturbed"), packets corrupted
(checksum error: the response carries -1 "transfer error", SM2 4.3 / 5.1 / 5.2), a line
outage in both directions, and Busy: with ``response_latency_s`` > 0 an update is
acknowledged that long after it arrived (the README's 10-24 ms command latency), and an
update that arrives before its predecessor's acknowledgement is answered -8 "busy error"
and not applied (SM2 5.1: "wait for the response packet"); ``busy_fraction`` answers -8 on
that fraction of updates at random (a device busy with itself).

What it does not model: the Motomed commands (SM2 4.4), the one shot mode, doublets and
triplets; the skin-resistance test pulse (SM2 1.2) is modelled only as the electrode error.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import ClassVar

import numpy as np


class _SM2:
    """The protocol's constants and framing, written here from SM2 on their own (the fake
    shares nothing with the driver's codec, so a misreading in one shows against the other)."""

    START, STOP, STUFFING_BYTE, STUFFING_KEY = 0xF0, 0x0F, 0x81, 0x55   # SM2 Table 6
    INIT_REPETITION_S, WATCHDOG_TIMEOUT_S = 0.5, 1.2                  # SM2 Table 7
    INIT, INIT_ACK, UNKNOWN_COMMAND, WATCHDOG = 1, 2, 3, 4             # SM2 3.1
    GET_STIM_MODE = 10                                                 # SM2 3.2
    INIT_CLM, START_CLM, STOP_CLM, SINGLE_PULSE = 30, 32, 34, 36       # SM2 3.3
    TRANSFER_ERROR, WRONG_MODE, BUSY = -1, -3, -8                      # SM2 5.1
    STIMULATION_ERROR = 38
    MAX_CURRENT_MA, MIN_PULSE_WIDTH_US, MAX_PULSE_WIDTH_US = 130, 20, 500   # SM2 4.3
    MIN_MAIN_INTERVAL_MS = 8.0                                         # SM2 4.3
    INTERPHASE_US = 100                                                # SM2 Figure 2
    STIM_ERROR_TEXT: ClassVar[dict[int, str]] = {
        -1: "emergency switch", -2: "electrode error",
        -3: "stimulation module error"}                                # SM2 4.3

    @staticmethod
    def crc8(data: bytes) -> int:        # SM2 2.2: CRC-8-CCITT, polynomial 0x07
        crc = 0
        for b in data:
            crc ^= b
            for _ in range(8):
                crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        return crc

    @classmethod
    def encode(cls, number: int, command: int, data: bytes = b"") -> bytes:
        raw = bytes((number, command)) + data
        payload = bytearray()
        for b in raw:                    # SM2 2.2: escape the constants but the key
            payload += bytes((cls.STUFFING_BYTE, b ^ cls.STUFFING_KEY)) \
                if b in (cls.START, cls.STOP, cls.STUFFING_BYTE) else bytes((b,))
        return bytes((cls.START, cls.STUFFING_BYTE, cls.crc8(bytes(payload)) ^ cls.STUFFING_KEY,
                      cls.STUFFING_BYTE, len(payload) ^ cls.STUFFING_KEY)) + \
            bytes(payload) + bytes((cls.STOP,))

    @staticmethod
    def u8(v: int) -> int:
        return v & 0xFF


sm2 = _SM2


class _Packet:
    def __init__(self, number: int, command: int, data: bytes):
        self.number, self.command, self.data = number, command, data

    @property
    def result(self) -> int:
        return (self.data[0] - 256 if self.data[0] > 127 else self.data[0]) if self.data else 0


class _Receiver:
    """SM2 2.2 framing and 5.2 error detection on the device side."""

    def __init__(self):
        self.buf = bytearray()
        self.transfer_errors: list[tuple[int, int]] = []
        """(packet number, command) of packets with a bad checksum or length (SM2 5.2:
        answered with the transfer error code)."""

    def feed(self, data: bytes) -> list[_Packet]:
        self.buf += data
        out: list[_Packet] = []
        while True:
            if sm2.START not in self.buf:
                self.buf.clear()
                return out
            del self.buf[:self.buf.index(sm2.START)]
            if len(self.buf) < 5:
                return out
            # SM2 4 "The First Bytes": start, stuffing byte, checksum, stuffing byte, length
            if self.buf[1] != sm2.STUFFING_BYTE or self.buf[3] != sm2.STUFFING_BYTE:
                del self.buf[:1]
                continue
            n = self.buf[4] ^ sm2.STUFFING_KEY
            cs = self.buf[2] ^ sm2.STUFFING_KEY
            k = self.buf.find(bytes((sm2.START,)), 5)
            if len(self.buf) < 6 + n:
                if k != -1:              # SM2 5.2 packet frame error: up to the 2nd start
                    del self.buf[:k]
                    continue
                return out
            payload = bytes(self.buf[5:5 + n])
            if self.buf[5 + n] != sm2.STOP:
                del self.buf[:k if k != -1 else len(self.buf)]
                continue
            del self.buf[:6 + n]
            raw = bytearray()
            it = iter(payload)
            for b in it:
                raw.append(next(it, 0) ^ sm2.STUFFING_KEY if b == sm2.STUFFING_BYTE else b)
            if len(raw) < 2:
                continue
            if sm2.crc8(payload) != cs:  # SM2 5.2 checksum error: Ack with transfer error
                self.transfer_errors.append((raw[0], raw[1]))
                continue
            out.append(_Packet(raw[0], raw[1], bytes(raw[2:])))


class SerialGone(OSError):
    """Raised by the fake port after :meth:`FakeRehastim2.unplug` (a USB glitch)."""


class FakePort:
    """One open handle of the device's FTDI serial port. A USB glitch
    (:meth:`FakeRehastim2.unplug`) invalidates it for good, as a re-enumerated USB device
    needs the port opened again."""

    def __init__(self, device: FakeRehastim2):
        self.device, self.generation = device, device.generation

    def _check(self) -> FakeRehastim2:
        if self.generation != self.device.generation:
            raise SerialGone("RehaStim2 USB serial port handle is stale (device re-plugged)")
        return self.device

    @property
    def in_waiting(self) -> int:
        return self._check().in_waiting

    def write(self, data: bytes) -> int:
        return self._check().write(data)

    def read(self, n: int = 1) -> bytes:
        return self._check().read(n)

    def reset_input_buffer(self) -> None:
        self._check().reset_input_buffer()

    def close(self) -> None:
        self.generation = -1


class FakeRehastim2:
    """The device: modes, acknowledgements, watchdog, stimulation errors, pulse output.

    Parameters
    ----------
    clock : callable() -> float
        Seconds (the bench's clock in fake mode).
    sleep : callable(float), optional
        How a blocking read waits (the bench's sleep).
    """

    PROTOCOL_VERSION = 1
    """SM2 4.1 Init byte 7: "Current version number of the protocol" (no value is given)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] | None = None, *,
                 response_latency_s: float = 0.0, busy_fraction: float = 0.0, seed: int = 0):
        self.clock, self._sleep = clock, sleep or (lambda s: time.sleep(min(s, 0.001)))
        self.response_latency_s = float(response_latency_s)
        self.busy_fraction = float(busy_fraction)
        self._rng = np.random.default_rng(seed)
        self._delayed: list[tuple[float, bytes]] = []   # acknowledgements not yet sent
        self._update_ack_due = -np.inf       # when the last update's ack goes out
        self._lose: dict[int, int] = {}      # command -> packets still to lose
        self._corrupt: dict[int, int] = {}   # command -> packets still to corrupt
        self._line_down_until = -np.inf
        self.lost: list[int] = []            # commands of the packets the line lost
        self.busy_replies = 0
        self.lock = threading.RLock()
        self._decoder = _Receiver()
        self._out = bytearray()
        self._number = 0                     # SM2 2.2: the device's own packet counter
        self.connected = False               # InitAck received (SM2 3.5)
        self.mode = 0                        # SM2 4.2: 0 start, 1 initialized, 2 started
        self.active: tuple[int, ...] = ()
        self.main_interval_s = 0.0
        self._last_valid = clock()
        self._next_init = clock()            # SM2 2.3: Init every InitRepetitionTime
        self.plugged = True
        self.generation = 0
        self.emergency_pressed = False
        self.electrode_error_channels: set[int] = set()
        # history of what was delivered: (time, {channel: (width_us, current_mA)})
        self.updates: list[tuple[float, dict[int, tuple[int, int]]]] = []
        self.starts: list[float] = []        # times stimulation was started (mode 1 -> 2)
        self.stops: list[float] = []
        self.received: list[_Packet] = []
        self.watchdog_expiries = 0

    # -- the serial port surface ----------------------------------------------------------
    def open(self, port: str = "") -> FakePort:
        """Open the serial port (a new handle; fails while unplugged)."""
        self._check_plugged()
        return FakePort(self)

    @property
    def in_waiting(self) -> int:
        self._check_plugged()
        with self.lock:
            self._advance()
            return len(self._out)

    def write(self, data: bytes) -> int:
        self._check_plugged()
        with self.lock:
            self._advance()
            if self.clock() < self._line_down_until:      # the line is out: nothing arrives
                self.lost.append(-1)
                return len(data)
            for pkt in self._decoder.feed(bytes(data)):
                if self._lose.get(pkt.command, 0) > 0:    # lost on the line (SM2 5.2)
                    self._lose[pkt.command] -= 1
                    self.lost.append(pkt.command)
                    continue
                if self._corrupt.get(pkt.command, 0) > 0:  # a flipped bit: checksum error
                    self._corrupt[pkt.command] -= 1
                    self._decoder.transfer_errors.append((pkt.number, pkt.command))
                    continue
                self._handle(pkt)
            for number, command in self._decoder.transfer_errors:
                # SM2 5.2 checksum / data length error: the Ack with the transfer error
                self._send(command + 1, bytes((sm2.u8(-1),)), number=number)
            self._decoder.transfer_errors.clear()
        return len(data)

    def read(self, n: int = 1, timeout_s: float = 0.05) -> bytes:
        self._check_plugged()
        deadline = time.monotonic() + timeout_s
        while True:
            with self.lock:
                self._advance()
                if self._out:
                    chunk = bytes(self._out[:n])
                    del self._out[:n]
                    return chunk
            if time.monotonic() >= deadline:
                return b""
            time.sleep(0.0005)

    def reset_input_buffer(self) -> None:
        with self.lock:
            self._out.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    # -- faults the tests and the fake bench inject ------------------------------------------
    def unplug(self) -> None:
        """USB lost: the port fails; the device stops (SM2 5.2: no valid packet within the
        WatchdogTimeout stops stimulation and resets all modes)."""
        with self.lock:
            self.plugged = False
            self.generation += 1
            self._stop_output("unplugged")
            self.mode, self.connected = 0, False

    def lose_next(self, command: int, count: int = 1) -> None:
        """The next ``count`` packets of ``command`` are lost on the line: the device never
        sees them, answers nothing and its watchdog is not fed (SM2 5.2)."""
        with self.lock:
            self._lose[command] = self._lose.get(command, 0) + count

    def corrupt_next(self, command: int, count: int = 1) -> None:
        """The next ``count`` packets of ``command`` arrive with a bad checksum: the device
        answers with the transfer error -1 and does not execute them (SM2 4.3, 5.1, 5.2)."""
        with self.lock:
            self._corrupt[command] = self._corrupt.get(command, 0) + count

    def line_down(self, duration_s: float) -> None:
        """Both directions of the line lose everything for ``duration_s`` from now."""
        with self.lock:
            self._line_down_until = self.clock() + duration_s

    def replug(self) -> None:
        with self.lock:
            self.plugged = True
            self._out.clear()
            self._next_init = self.clock()

    def press_emergency_switch(self) -> None:
        """SM2 1.3 "Stimulation errors" / 4.3 StimulationError -1: stimulation stops, the
        mode resets to start mode, the error is sent to the PC."""
        with self.lock:
            self.emergency_pressed = True
            self._stimulation_error(-1)

    def release_emergency_switch(self) -> None:
        with self.lock:
            self.emergency_pressed = False

    def electrode_error(self, channel: int) -> None:
        """SM2 1.2 (skin resistance check) and 4.3 StimulationError -2."""
        with self.lock:
            self.electrode_error_channels.add(channel)
            if self.mode == 2 and channel in self.active:
                self._stimulation_error(-2)

    # -- protocol --------------------------------------------------------------------------
    def _check_plugged(self) -> None:
        if not self.plugged:
            raise SerialGone("RehaStim2 USB serial port lost (fake unplugged)")

    def _send(self, command: int, data: bytes = b"", number: int | None = None) -> None:
        if number is None:                   # information packets: own counter (SM2 2.2)
            number = self._number
            self._number = (self._number + 1) & 0xFF
        frame = sm2.encode(number, command, data)
        if self.clock() < self._line_down_until:
            return                           # lost on the way back
        self._out += frame

    def _advance(self) -> None:
        now = self.clock()
        if not self.plugged:
            return
        while self._delayed and self._delayed[0][0] <= now:   # acknowledgements now due
            _due, frame = self._delayed.pop(0)
            if now >= self._line_down_until:
                self._out += frame
        if self.connected and now - self._last_valid > sm2.WATCHDOG_TIMEOUT_S:
            # SM2 5.2 "Data transfer physically broken / disturbed": stimulation stopped,
            # all modes reset, RehaStim2 sends the Init command
            self.watchdog_expiries += 1
            self._stop_output("watchdog", at=self._last_valid + sm2.WATCHDOG_TIMEOUT_S)
            self.mode, self.connected = 0, False
            self._next_init = now
        if not self.connected and now >= self._next_init:   # SM2 2.3, 5.3
            self._send(sm2.INIT, bytes((self.PROTOCOL_VERSION,)))
            self._next_init = now + sm2.INIT_REPETITION_S

    def _ack(self, pkt: _Packet, result: int, extra: bytes = b"") -> None:
        # SM2 2.2: the response echoes the PC's packet number; 4.x: command + 1
        self._send(pkt.command + 1, bytes((sm2.u8(result),)) + extra, number=pkt.number)

    def _handle(self, pkt: _Packet) -> None:
        now = self.clock()
        self.received.append(pkt)
        self._last_valid = now               # SM2 2.3: a valid packet feeds the watchdog
        c = pkt.command
        if c == sm2.INIT_ACK:                # SM2 4.1 InitAck: result 0 = connected
            if pkt.result == 0:
                self.connected = True
            return
        if not self.connected:
            return                           # SM2 3.5: the connection starts with Init
        if c == sm2.WATCHDOG:                # SM2 4.1: no response
            return
        if c == sm2.GET_STIM_MODE:           # SM2 4.2
            self._ack(pkt, 0, bytes((self.mode,)))
        elif c == sm2.INIT_CLM:
            self._init_clm(pkt)
        elif c == sm2.START_CLM:
            self._start_clm(pkt, now)
        elif c == sm2.STOP_CLM:              # SM2 4.3 StopChannelListMode
            self._stop_output("stop", at=now)
            self.mode = 0                    # SM2 Figure 4: Stop returns to start mode
            self._ack(pkt, 0)
        elif c == sm2.SINGLE_PULSE:          # SM2 4.3: only from start mode (Figure 4)
            self._ack(pkt, 0 if self.mode == 0 else -3)
        else:                                # SM2 5.2 "Unknown command error"
            self._send(sm2.UNKNOWN_COMMAND, bytes((c,)), number=pkt.number)

    def _init_clm(self, pkt: _Packet) -> None:
        if self.mode != 0:                   # SM2 Figure 4: from start mode only
            self._ack(pkt, -3)
            return
        d = pkt.data
        if len(d) != 7:                      # SM2 5.2 too many / few parameters
            self._ack(pkt, -2)
            return
        lf, mask, _lf_mask, ipi, msb, lsb, execution = d
        main_code = (msb << 8) | lsb
        main_ms = main_code * 0.5 + 1.0
        ipi_ms = ipi * 0.5 + 1.5
        if lf > 7 or mask == 0 or main_code > 2048 or execution > 1 or \
                (main_code > 0 and main_ms < sm2.MIN_MAIN_INTERVAL_MS) or ipi_ms < 8.0:
            self._ack(pkt, -2)               # SM2 4.3 ranges, "minimum ... is 8 ms"
            return
        self.active = tuple(ch for ch in range(1, 9) if mask >> (ch - 1) & 1)
        self.main_interval_s = main_ms / 1000.0
        self.mode = 1
        self._ack(pkt, 0)

    def _start_clm(self, pkt: _Packet, now: float) -> None:
        if self.mode not in (1, 2):          # SM2 Figure 4: after InitChannelListMode
            self._ack(pkt, -3)
            return
        d = pkt.data
        params = None if len(d) != 4 * len(self.active) else [
            (d[4 * i], (d[4 * i + 1] << 8) | d[4 * i + 2], d[4 * i + 3])
            for i in range(len(self.active))]   # SM2 4.3: 4 bytes per active channel
        if params is None or any(m > 2 or pw > sm2.MAX_PULSE_WIDTH_US or
                                 cur > sm2.MAX_CURRENT_MA for m, pw, cur in params):
            self._ack(pkt, -2)               # SM2 4.3 StartChannelListMode ranges
            return
        if self.emergency_pressed:           # SM2 1.3: switch activated or not connected
            self._ack(pkt, 0)
            self._stimulation_error(-1)
            return
        # SM2 4.3: "if (pw < 20) then pw = 20"
        values = {ch: (max(pw, sm2.MIN_PULSE_WIDTH_US), cur)
                  for ch, (_m, pw, cur) in zip(self.active, params, strict=True)}
        if now < self._update_ack_due or (self.busy_fraction > 0 and
                                           self._rng.random() < self.busy_fraction):
            # SM2 5.1 -8 busy error: "wait for the response packet" of the predecessor
            # before sending the next command; the update is not applied
            self.busy_replies += 1
            self._ack(pkt, sm2.BUSY)
            return
        if self.mode == 1:
            self.starts.append(now)
        self.mode = 2
        self.updates.append((now, values))
        if self.response_latency_s > 0:      # acknowledged after the command latency
            self._update_ack_due = now + self.response_latency_s
            self._delayed.append((self._update_ack_due, sm2.encode(
                pkt.number, pkt.command + 1, bytes((0,)))))
        else:
            self._ack(pkt, 0)
        bad = [ch for ch in self.active if ch in self.electrode_error_channels
               and values[ch][1] > 0]
        if bad:                              # SM2 1.2: no pulse on a bad resistance
            self._stimulation_error(-2)

    def _stimulation_error(self, code: int) -> None:
        # SM2 1.3: stops the stimulation, resets to start mode, sends StimulationError
        self._stop_output(sm2.STIM_ERROR_TEXT[code])
        self.mode = 0
        self._send(sm2.STIMULATION_ERROR, bytes((sm2.u8(code),)))

    def _stop_output(self, why: str, at: float | None = None) -> None:
        if self.mode == 2:
            self.stops.append(self.clock() if at is None else at)
            self.updates.append((self.stops[-1], {}))

    # -- what the fake bench samples --------------------------------------------------------
    @property
    def started_at(self) -> float | None:
        """Time stimulation last started (no trigger output exists: SM2 has none)."""
        return self.starts[-1] if self.starts else None

    def amplitude_mA_at(self, channel_1based: int, t) -> np.ndarray:
        """The current of the pulses ``channel`` delivers at times ``t`` (0 when stopped)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        with self.lock:
            hist = list(self.updates)
        if not hist:
            return np.zeros(len(t))
        times = np.array([h[0] for h in hist])
        vals = np.array([h[1].get(channel_1based, (0, 0))[1] for h in hist], dtype=float)
        k = np.searchsorted(times, t, side="right") - 1
        return np.where(k >= 0, vals[np.clip(k, 0, len(vals) - 1)], 0.0)

    # the bench's stimulator surface (0-based channels, nA, like the fake STG)
    def envelope_at(self, channel: int, t) -> np.ndarray:
        return self.amplitude_mA_at(channel + 1, t) * 1e6

    def current_at(self, channel: int, t) -> np.ndarray:
        """Biphasic pulses (SM2 Figure 2): +I for the width, 100 us pause, -I for the width,
        one per main interval in the channel's 1.5 ms slot (SM2 1.3)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if self.main_interval_s <= 0 or not self.starts:
            return np.zeros(len(t))
        with self.lock:
            hist = list(self.updates)
        widths = [h[1].get(channel + 1, (0, 0))[0] for h in hist if h[1]]
        pw = (widths[-1] if widths else 0) * 1e-6
        slot = self.active.index(channel + 1) * 1.5e-3 if channel + 1 in self.active else 0.0
        phase = np.mod(t - self.starts[-1] - slot, self.main_interval_s)
        # a pulse is generated whole with the parameters in force when it begins (SM2 1.3)
        amp = self.amplitude_mA_at(channel + 1, t - phase) * 1e6
        ip = sm2.INTERPHASE_US * 1e-6
        return np.where(phase < pw, amp, np.where((phase >= pw + ip) & (phase < 2 * pw + ip),
                                                  -amp, 0.0))

    def sync_at(self, sync: int, t) -> np.ndarray:
        """The RehaStim2 has no sync output (SM2 describes none): always low."""
        return np.zeros(len(np.atleast_1d(t)))
