"""A fake Hasomed P24 or RehaMove3 at the serial byte level, written from the ScienceMode4
documents.

Sources (cited beside each behaviour): *IFU*, "P24 Science & P24 Module, Instructions for
Use" v1.1 (its ScienceMode chapter, Tables 1-27, and Technical Specification); *RM3*,
"ScienceMode RehaMove3 Description and Protocol" 2018-04-21, sections 1-7; *smpt*, Hasomed's
C library (``ScienceMode4_c_library``), file named. The framing is written here again from
the documents (the fake shares nothing with the driver's codec, so a misreading in one shows
against the other); the device's behaviour (levels, acknowledgements, errors, the mid-level
keep-alive) is modelled from the same sections.

The fake is a serial port object (``write``, ``read``, ``in_waiting``, ``close``,
``reset_input_buffer``, as pyserial's), on a clock (the fake bench's in fake mode).

Faults the tests inject: packets lost on the line (no answer), packets arriving corrupted
(IFU Table 27: answered with the transfer error 01, not executed), replies corrupted on the
way back, the line down in both directions, an electrode error (IFU Table 27: 10), an unplug.

Not modelled: the measurement samples of Ll_channel_config_ack (IFU Table 17), the I24/EMG
commands, the ramp of Ml_update (IFU Table 22; pulses start at full current here).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

START, STOP, STUFF, KEY = 0xF0, 0x0F, 0x81, 0x55                 # IFU Table 3
LL_INIT, LL_CONFIG, LL_STOP = 0, 2, 4                            # IFU Table 11
ML_INIT, ML_UPDATE, ML_STOP, ML_GET_CURRENT_DATA = 30, 32, 34, 36   # RM3 5.1 (smpt: 36)
GET_DEVICE_ID, RESET, GET_STIM_STATUS, UNKNOWN_CMD = 52, 58, 62, 67  # IFU Table 4
KEEPALIVE_TIMEOUT_S = 2.0                                        # IFU "Mid-Level Update"
MAX_CURRENT_MA = 130.0                         # IFU Technical Specification; RM3 1.2
MODELS = {"P24": {"connectors": 2, "reset_ack": True},           # IFU Table 14: connector 0-1
          "RehaMove3": {"connectors": 1, "reset_ack": False}}    # RM3 4.2 reserved; 3.1
HOLD_S = 0.1
"""The bench's muscle sees a channel's last low-level pulse current this long (a stand-in
for the twitch summation of the fake participant; no device behaviour)."""


def _crc(data: bytes) -> int:                # IFU "Packet Structure": CRC-CCITT, 16 bits
    crc = 0
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def _encode(number: int, command: int, data: bytes) -> bytes:
    raw = bytes(((number << 2) | (command >> 8), command & 0xFF)) + data
    body = b"".join(bytes((STUFF, b ^ KEY)) if b in (START, STOP, STUFF) else bytes((b,))
                    for b in raw)
    n, cs = len(body) + 10, _crc(body)
    return bytes((START, STUFF, (n >> 8) ^ KEY, STUFF, (n & 0xFF) ^ KEY, STUFF,
                  (cs >> 8) ^ KEY, STUFF, (cs & 0xFF) ^ KEY)) + body + bytes((STOP,))


def _frames(buf: bytearray) -> list[tuple[bytes, bool]]:
    """(unstuffed prefix + data, checksum and length fine) of each complete frame."""
    out = []
    while START in buf:
        del buf[:buf.index(START)]
        end, i = -1, 1
        while i < len(buf):               # IFU "Packet Structure": after a stuffing byte
            if buf[i] == STUFF:           # comes a value, never a start or stop byte
                i += 2
                continue
            if buf[i] in (START, STOP):
                end = i
                break
            i += 1
        if end == -1:
            break
        if buf[end] == START:             # a packet cut short: the new one counts
            del buf[:end]
            continue
        frame = bytes(buf[:end + 1])
        del buf[:end + 1]
        if len(frame) < 12:
            continue
        body = frame[9:-1]
        raw, it = bytearray(), iter(body)
        for b in it:
            raw.append(next(it, 0) ^ KEY if b == STUFF else b)
        n = ((frame[2] ^ KEY) << 8) | (frame[4] ^ KEY)
        cs = ((frame[6] ^ KEY) << 8) | (frame[8] ^ KEY)
        out.append((bytes(raw), n == len(frame) and cs == _crc(body)))
    return out


class SerialGone(OSError):
    """The fake port after :meth:`FakeSm4.unplug`."""


class FakePort:
    def __init__(self, device: FakeSm4):
        self.device, self.generation = device, device.generation

    def _dev(self) -> FakeSm4:
        if self.generation != self.device.generation:
            raise SerialGone("ScienceMode4 USB serial port handle is stale (re-plugged)")
        return self.device

    @property
    def in_waiting(self) -> int:
        return self._dev().in_waiting

    def write(self, data: bytes) -> int:
        return self._dev().write(data)

    def read(self, n: int = 1) -> bytes:
        return self._dev().read(n)

    def reset_input_buffer(self) -> None:
        self._dev().reset_input_buffer()

    def close(self) -> None:
        self.generation = -1


class FakeSm4:
    """The device: levels, acknowledgements, pulses, the mid-level keep-alive, errors.

    Parameters
    ----------
    model : "P24" or "RehaMove3"
    clock : callable() -> float
        Seconds (the bench's clock in fake mode).
    response_latency_s : float or (low, high)
        Time from a command's arrival to its answer; a pair draws each answer's latency
        uniformly between the two (issue 43: the P24 answers in 5-15 ms, so an answer may
        come after the next pulse is due at 100 Hz).
    seed : int
        Of the latency draws.
    """

    def __init__(self, model: str = "P24", clock: Callable[[], float] = time.monotonic,
                 response_latency_s: float | tuple[float, float] = 0.002, seed: int = 0):
        self.model, self.spec = model, MODELS[model]
        self.clock = clock
        low, high = (response_latency_s if isinstance(response_latency_s, tuple)
                     else (response_latency_s, response_latency_s))
        self.latency_s = (float(low), float(high))
        self._rng = np.random.default_rng(seed)
        self.lock = threading.RLock()
        self._in = bytearray()
        self._out = bytearray()
        self._delayed: list[tuple[float, bytes]] = []
        self._lose: dict[int, int] = {}
        self._corrupt: dict[int, int] = {}
        self._corrupt_reply: dict[int, int] = {}
        self._line_down_until = -np.inf
        self.plugged, self.generation = True, 0
        self.level = 0                   # IFU Table 7: 0 none, 1 LL, 2 ML, 3 ML running
        self.ml: dict[int, tuple[float, list[tuple[int, float]]]] = {}
        self.ml_started_at = 0.0
        self._last_keepalive = 0.0
        self.keepalive_expiries = 0
        self.electrode_error_channels: set[int] = set()
        self.pulses: list[tuple[float, int, float, int]] = []
        """(time, channel 1-based, current mA, phase width us) of each low-level pulse."""
        self.pulse_points: list[list[tuple[int, float]]] = []
        """The points of each pulse as executed (IFU Table 15: duration us, current mA)."""
        self.ml_spans: list[tuple[float, float, dict]] = []
        """(start, end or inf, channels) of each mid-level run."""
        self.received: list[tuple[int, int]] = []      # (number, command) executed
        self.lost: list[int] = []
        self.transfer_errors = 0
        self.stops: list[float] = []

    # -- the serial port surface ----------------------------------------------------------
    def open(self, port: str = "") -> FakePort:
        if not self.plugged:
            raise SerialGone(f"no {self.model} on {port!r} (fake unplugged)")
        return FakePort(self)

    @property
    def in_waiting(self) -> int:
        self._check()
        with self.lock:
            self._advance()
            return len(self._out)

    def write(self, data: bytes) -> int:
        self._check()
        with self.lock:
            self._advance()
            if self.clock() < self._line_down_until:
                self.lost.append(-1)
                return len(data)
            self._in += bytes(data)
            for raw, fine in _frames(self._in):
                number, command = raw[0] >> 2, ((raw[0] & 3) << 8) | raw[1]
                if self._lose.get(command, 0) > 0:         # lost on the line: no answer
                    self._lose[command] -= 1
                    self.lost.append(command)
                    continue
                if self._corrupt.get(command, 0) > 0:
                    self._corrupt[command] -= 1
                    fine = False
                if not fine:      # IFU Table 27 01: "check sum and/or length do not match"
                    self.transfer_errors += 1
                    self._reply(number, command + 1, bytes((1,)))
                    continue
                self._handle(number, command, raw[2:])
        return len(data)

    def read(self, n: int = 1) -> bytes:
        self._check()
        with self.lock:
            self._advance()
            chunk = bytes(self._out[:n])
            del self._out[:n]
            return chunk

    def reset_input_buffer(self) -> None:
        with self.lock:
            self._out.clear()

    def close(self) -> None:
        pass

    # -- faults ----------------------------------------------------------------------------
    def lose_next(self, command: int, count: int = 1) -> None:
        """The next ``count`` packets of ``command`` never reach the device."""
        with self.lock:
            self._lose[command] = self._lose.get(command, 0) + count

    def corrupt_next(self, command: int, count: int = 1) -> None:
        """The next ``count`` packets of ``command`` arrive with a bad checksum."""
        with self.lock:
            self._corrupt[command] = self._corrupt.get(command, 0) + count

    def corrupt_next_reply(self, command: int, count: int = 1) -> None:
        """The next ``count`` answers to ``command`` reach the host with a flipped bit."""
        with self.lock:
            self._corrupt_reply[command] = self._corrupt_reply.get(command, 0) + count

    def line_down(self, duration_s: float) -> None:
        with self.lock:
            self._line_down_until = self.clock() + duration_s

    def electrode_error(self, channel: int) -> None:
        """The skin-resistance check fails on ``channel`` (1-based; RM3 1.3)."""
        with self.lock:
            self.electrode_error_channels.add(channel)

    def unplug(self) -> None:
        with self.lock:
            self.plugged = False
            self.generation += 1
            self._end_ml(self.clock())
            self.level = 0

    # -- protocol ----------------------------------------------------------------------------
    def _check(self) -> None:
        if not self.plugged:
            raise SerialGone(f"{self.model} USB serial port lost (fake unplugged)")

    def _reply(self, number: int, command: int, data: bytes, at: float | None = None) -> None:
        frame = bytearray(_encode(number, command, data))
        if self._corrupt_reply.get(command - 1, 0) > 0:
            self._corrupt_reply[command - 1] -= 1
            frame[-2] ^= 0x04
        low, high = self.latency_s
        due = (self.clock() if at is None else at) + (
            low if high <= low else float(self._rng.uniform(low, high)))
        self._delayed.append((due, bytes(frame)))
        self._delayed.sort(key=lambda d: d[0])

    def _advance(self) -> None:
        now = self.clock()
        while self._delayed and self._delayed[0][0] <= now:
            due, frame = self._delayed.pop(0)
            if not due < self._line_down_until:
                self._out += frame
        if self.level == 3 and now - self._last_keepalive > KEEPALIVE_TIMEOUT_S:
            # IFU "Mid-Level Update", RM3 5.1: "automatic timeout of 2 s"; "the stimulation
            # can be started again with Ml_update": back to initialised
            self.keepalive_expiries += 1
            self._end_ml(self._last_keepalive + KEEPALIVE_TIMEOUT_S)
            self.level = 2

    def _end_ml(self, at: float) -> None:
        if self.ml_spans and self.ml_spans[-1][1] == np.inf:
            s, _, chans = self.ml_spans[-1]
            self.ml_spans[-1] = (s, max(at, s), chans)

    def _handle(self, number: int, command: int, data: bytes) -> None:
        now = self.clock()
        self.received.append((number, command))
        ack = command + 1
        if command == GET_STIM_STATUS:            # IFU Table 7: result, level, voltage
            self._reply(number, ack, bytes((0, self.level, 6 if self.level else 1)))
        elif command == GET_DEVICE_ID:            # IFU Table 5: result, 10 chars
            self._reply(number, ack, bytes((0,)) + f"{self.model[:3]}0000001".encode()[:10])
        elif command == RESET:                    # RM3 3.1: Reset_ack "currently not send"
            self._end_ml(now)
            self.level = 0
            if self.spec["reset_ack"]:
                self._reply(number, ack, bytes((0,)))
        elif command == LL_INIT:                  # IFU "Low-Level Initialization"
            ok = self.level == 0                  # smpt: no other level initialised
            if ok:
                self.level = 1
            self._reply(number, ack, bytes((0 if ok else 7,)))
        elif command == LL_CONFIG:
            self._ll_config(number, data, now)
        elif command == LL_STOP:                  # IFU "Low-Level Stop"
            was = self.level == 1
            self.level = 0 if was else self.level
            self.stops.append(now)
            self._reply(number, ack, bytes((0 if was else 7,)))
        elif command == ML_INIT:                  # IFU "Mid-Level initialization"
            ok = self.level == 0
            self.level = 2 if ok else self.level
            self._reply(number, ack, bytes((0 if ok else 7,)))
        elif command == ML_UPDATE:
            self._ml_update(number, data, now)
        elif command == ML_GET_CURRENT_DATA:      # RM3 5.2/5.3: the keep-alive
            if self.level in (2, 3):
                self._last_keepalive = now
            errs = sum(1 << (c - 1) for c in self.electrode_error_channels if c <= 4)
            self._reply(number, ack, bytes((0 if self.level in (2, 3) else 7, 2,
                                            (0x10 if self.level == 3 else 0) | errs)))
        elif command == ML_STOP:                  # IFU "Mid-Level Stop"
            was = self.level in (2, 3)
            self._end_ml(now)
            self.level = 0 if was else self.level
            self.stops.append(now)
            self._reply(number, ack, bytes((0 if was else 7,)))
        else:                                     # IFU Table 10: Unknown_cmd, 11
            self._reply(number, UNKNOWN_CMD, bytes((11,)))

    def _channel(self, first: int) -> tuple[int, int] | None:
        channel, connector = (first >> 5) & 3, (first >> 4) & 1
        if connector >= self.spec["connectors"]:  # RM3 4.2: the bit is reserved (0)
            return None
        return channel, connector

    def _ll_config(self, number: int, data: bytes, now: float) -> None:
        ack = LL_CONFIG + 1
        where = self._channel(data[0]) if data else None
        n = (data[0] & 0x0F) + 1 if data else 0
        if self.level != 1:                       # IFU Table 27 07: not initialised
            self._reply(number, ack, bytes((7, 0, 0)))
            return
        if where is None or len(data) != 1 + 4 * n:   # IFU Table 27 02: parameter error
            self._reply(number, ack, bytes((2, 0, 0)))
            return
        channel, connector = where
        ch1 = connector * 4 + channel + 1
        pts = []
        for i in range(n):
            b = data[1 + 4 * i:5 + 4 * i]
            pts.append(((b[0] << 4) | (b[1] >> 4), ((((b[1] & 0xF) << 6) | (b[2] >> 2)) - 300)
                        / 2))
        if any(abs(c) > MAX_CURRENT_MA for _, c in pts):   # smpt_is_valid_point
            self._reply(number, ack, bytes((2, (connector << 4) | channel, 0)))
            return
        if ch1 in self.electrode_error_channels:  # RM3 1.3: the pulse is not executed
            self._reply(number, ack, bytes((10, (connector << 4) | channel, 0)))
            return
        if data[0] & 0x80:                        # IFU Table 14 bit 7: execute
            self.pulses.append((now, ch1, float(max(c for _, c in pts)), int(pts[0][0])))
            self.pulse_points.append(pts)
        # IFU "Ll_channel_config_ack ... sent after the stimulation has been executed";
        # smpt_extract_ll_channel_config_ack: channel low nibble, connector high nibble
        done = now + sum(t for t, _ in pts) * 1e-6
        self._reply(number, ack, bytes((0, (connector << 4) | channel, 0)), at=done)

    def _ml_update(self, number: int, data: bytes, now: float) -> None:
        ack = ML_UPDATE + 1
        if self.level not in (2, 3):
            self._reply(number, ack, bytes((7,)))
            return
        chans: dict[int, tuple[float, float]] = {}
        try:
            mask, i = data[0], 1
            for ch in range(8):
                if not mask & (1 << ch):
                    continue
                n = (data[i] >> 4) + 1
                period_ms = (((data[i + 1] << 8) | data[i + 2]) >> 1) / 2    # IFU Table 22
                i += 3
                cur = 0.0
                for _ in range(n):
                    b = data[i:i + 4]
                    cur = max(cur, ((((b[1] & 0xF) << 6) | (b[2] >> 2)) - 300) / 2)
                    i += 4
                if period_ms <= 0 or cur > MAX_CURRENT_MA:
                    raise ValueError
                chans[ch + 1] = (period_ms, cur)
            if i != len(data):
                raise ValueError
        except (ValueError, IndexError):          # IFU Table 27 02
            self._reply(number, ack, bytes((2,)))
            return
        self._end_ml(now)
        self.ml_spans.append((now, np.inf, chans))
        self.level, self._last_keepalive = 3, now   # an Ml_update also keeps it alive
        self._reply(number, ack, bytes((0,)))

    # -- what the fake bench samples --------------------------------------------------------
    @property
    def started_at(self) -> float | None:
        """The first pulse of the last run (ScienceMode4 has no trigger output)."""
        with self.lock:
            if self.pulses:
                return self.pulses[-1][0] if not self.ml_spans else max(
                    self.pulses[-1][0], self.ml_spans[-1][0])
            return self.ml_spans[-1][0] if self.ml_spans else None

    def amplitude_mA_at(self, channel_1based: int, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        with self.lock:
            ps = [(p[0], p[2]) for p in self.pulses if p[1] == channel_1based]
            spans = list(self.ml_spans)
        out = np.zeros(len(t))
        if ps:
            times = np.array([p[0] for p in ps])
            vals = np.array([p[1] for p in ps])
            k = np.searchsorted(times, t, side="right") - 1
            recent = (k >= 0) & (t - times[np.clip(k, 0, None)] <= HOLD_S)
            out = np.where(recent, vals[np.clip(k, 0, None)], 0.0)
        for s, e, chans in spans:
            if channel_1based in chans:
                out = np.where((t >= s) & (t < e), chans[channel_1based][1], out)
        return out

    def envelope_at(self, channel: int, t) -> np.ndarray:
        """The bench's surface (0-based channel, nA)."""
        return self.amplitude_mA_at(channel + 1, t) * 1e6

    def current_at(self, channel: int, t) -> np.ndarray:
        """Low-level pulses as output, point by point (IFU Table 15), nA."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.zeros(len(t))
        with self.lock:
            ps = [(p[0], pts) for p, pts in zip(self.pulses, self.pulse_points, strict=True)
                  if p[1] == channel + 1]
        for t0, pts in ps:
            edge = t0
            for dur_us, cur in pts:
                end = edge + dur_us * 1e-6
                out[(t >= edge) & (t < end)] = cur * 1e6
                edge = end
        return out

    def sync_at(self, sync: int, t) -> np.ndarray:
        """No sync output is described (IFU, RM3): always low."""
        return np.zeros(len(np.atleast_1d(t)))
