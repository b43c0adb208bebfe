"""An emulated Leptrino 6-axis force sensor on a pseudo-terminal or an in-process port.

Two transports, chosen through :func:`nmsid.protocols.os_platform.is_windows` (or
``transport=``): on POSIX the emulator owns the master side of an ``os.openpty()`` pair
and the driver opens the slave side (``emulator.port``, a path) with pyserial exactly as
it opens the sensor's virtual COM port; on Windows, which has no ``pty`` / ``tty``
(imported lazily, only for the POSIX transport), ``emulator.port`` is a pyserial URL
``leptrinoemu://<name>`` served in-process by :mod:`nmsid.testing.fakes.protocol_leptrinoemu`
(registered in pyserial's ``protocol_handler_packages``). Either way it runs in a thread. Its byte
codec is written independently of ``drivers.leptrino_protocol`` (so a shared mistake cannot pass
unnoticed): frames are ``DLE STX LEN TERM CMD RES DATA DLE ETX BCC`` with DLE doubled inside and
BCC = XOR of the unstuffed payload and ETX; a command with a bad BCC is answered ``DLE NAK``.

Faults, settable from a test while it runs: ``nak_next`` (answer the next N commands with
NAK), ``corrupt_every`` (every Nth data frame gets a wrong BCC), ``garbage_every`` (random
bytes between frames), ``fragment`` (write in 1..7-byte pieces with pauses, so the driver
sees partial reads), ``error_result`` (answer a command with an error result code),
``status_fn`` (status byte per record), ``data_result`` (result code in data frames),
``corrupt_replies`` (break the BCC
of the next N command replies), :meth:`inject` (raw bytes, e.g. a
spontaneous ``DLE NAK``), :meth:`stall` (stop streaming but stay
connected), :meth:`unplug` (close the master side: the driver's port errors out) and
:meth:`replug` (a new pseudo-terminal behind the same ``port`` path, like a sensor that
re-enumerates after a USB glitch; the old handle stays dead).

Behaviour modelled from the vendor's material, not from ``drivers.leptrino`` (the
specification is Leptrino's "communication format specification" Ver 1.13, ``doc/protocal.pdf``
of ``hiveground-ros-package/leptrino_force_torque``; section numbers below are its):

* Product information, 5.1: LEN $20, model 16, serial 8, firmware 4 bytes, and NO rate
  field: ``rate_text=None`` is the default. The C sample's ``ST_R_GET_INF`` has a 6-byte
  rate text after the firmware (``pCommon.h`` ``FREQ_SIZE``): ``rate_text="1.2 kH"`` etc.
  adds it. Whatever it states, the records stream at ``rate_Hz`` (independent of it).
* Start, 6.2: "the sensor sends the response to this command, then sends data until it
  receives the stop command": a bare response (LEN 4, $32, result) precedes the records.
* NAK, 2.4.3: a command with a bad BCC is answered ``DLE NAK`` and "the host must resend
  the command"; ``nak_next`` NAKs the next N commands (0x32 included).
* Digital filter, 5.3: $B6 answers LEN 8 with the setting ($00 OFF, $01 10 Hz, $02 100 Hz,
  $03 200 Hz; ``filter_code``, 100 Hz = $02 by default, the issue's "100 Hz by default")
  and 3 reserved bytes.
* Data, 6: "-32000 .. +32000", rated = +-10000, "a force above 3.2 times the rating is also
  +-32000": raw values are clipped at +-32000.
* Data record, 6.1: six int16 values, two reserved bytes, the status byte, one reserved
  byte. Status bits 0, 1, 2 are documented; bits 3-7 are reserved and undefined, so with
  ``reserved_bits_random`` each record carries random values there and in the two bytes
  after Mz (which an earlier reading took as a temperature and bit 5 as an external
  input; 6.1 defines neither). ``status_fn`` may set any bit, reserved ones included.
"""

from __future__ import annotations

import itertools
import os
import random
import struct
import tempfile
import threading
import time

from nmsid.protocols import os_platform

DLE, STX, ETX, NAK = 0x10, 0x02, 0x03, 0x15
FULL_SCALE = 32000


class _PtyTransport:
    """POSIX: a pseudo-terminal; the driver opens the slave's path (a stable symlink)."""

    def __init__(self, port: str):
        import tty  # noqa: PLC0415 (POSIX only; never imported on Windows)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        tmp = port + ".new"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, port)

    def recv(self, timeout_s: float) -> bytes:
        import select  # noqa: PLC0415 (select on a pty fd: POSIX only)
        ready, _, _ = select.select([self.master], [], [], timeout_s)
        if not ready:
            return b""
        try:
            return os.read(self.master, 4096)
        except BlockingIOError:
            return b""

    def send(self, data: bytes) -> int:
        return os.write(self.master, data)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master = self.slave = -1


class InProcessTransport:
    """Windows (and tests): two byte buffers between the emulator thread and the
    pyserial handler :mod:`nmsid.testing.fakes.protocol_leptrinoemu`."""

    def __init__(self):
        self.to_host = bytearray()
        self.to_sensor = bytearray()
        self.cond = threading.Condition()
        self.closed = False

    def recv(self, timeout_s: float) -> bytes:
        with self.cond:
            if not self.to_sensor and not self.closed:
                self.cond.wait(timeout_s)
            if self.closed:
                raise OSError("transport closed")
            data, self.to_sensor[:] = bytes(self.to_sensor), b""
            return data

    def send(self, data: bytes) -> int:
        with self.cond:
            if self.closed:
                raise OSError("transport closed")
            self.to_host += data
            self.cond.notify_all()
            return len(data)

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()


_INPROCESS: dict[str, LeptrinoEmulator] = {}
"""In-process emulators by name (``leptrinoemu://<name>``)."""
_names = itertools.count(1)


def inprocess_transport(name: str) -> InProcessTransport:
    """The current transport of the in-process emulator ``name`` (for the pyserial handler).

    Raises
    ------
    OSError
        No such emulator, or it is unplugged.
    """
    emu = _INPROCESS.get(name)
    if emu is None or emu._unplugged or not isinstance(emu.transport, InProcessTransport):
        raise OSError(f"could not open port leptrinoemu://{name}: no such device")
    return emu.transport


def _frame(payload: bytes) -> bytes:
    check = ETX
    out = bytearray([DLE, STX])
    for b in payload:
        check ^= b
        out.append(b)
        if b == DLE:
            out.append(b)
    out += bytes([DLE, ETX, check])
    return bytes(out)


class LeptrinoEmulator:
    """Emulated sensor. Use as a context manager; ``port`` is the path to open."""

    def __init__(self, *, rate_Hz: float = 1200.0, rated=(500.0, 500.0, 1000.0, 10.0, 10.0, 10.0),
                 wrench_fn=None, model: str = "PFS080YA501G6", serial: str = "LT000042",
                 firmware: str = "1.07", seed: int = 0, rate_text: str | None = None,
                 reserved_bits_random: bool = False,
                 filter_code: int = 0x02, transport: str | None = None):
        self.rate_Hz = rate_Hz
        self.rated = tuple(float(r) for r in rated)
        self.wrench_fn = wrench_fn or (lambda t: (2.0, -1.0, 0.5, 0.01, 0.0, -0.02))
        self.status_fn = lambda t: 0
        self.model, self.serial, self.firmware = model, serial, firmware
        self.rate_text = rate_text
        self.filter_code = filter_code
        self.reserved_bits_random = reserved_bits_random
        self.rng = random.Random(seed)
        self.nak_next = 0
        self.nak_start = 0
        """NAK the next N start commands (0x32) only (2.4.3: the host resends)."""
        self.corrupt_every = 0
        self.garbage_every = 0
        self.fragment = False
        self.error_result: dict[int, int] = {}
        self.data_result = 0
        self.corrupt_replies = 0
        self.commands: list[int] = []
        self.bad_commands = 0
        self.frames_sent = 0
        self.frames_dropped = 0
        self._streaming = False
        self._stalled = False
        self._t0 = 0.0
        self._stream_sent = 0
        self._out = bytearray()
        self._rx = bytearray()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        if transport is None:
            transport = "inprocess" if os_platform.is_windows() else "pty"
        if transport not in ("pty", "inprocess"):
            raise ValueError(f"transport must be 'pty' or 'inprocess', not {transport!r}")
        self.transport_kind = transport
        self._dir = ""
        if transport == "pty":
            self._dir = tempfile.mkdtemp(prefix="leptrino-emu-")
            self.port = os.path.join(self._dir, "ttyLEPTRINO")
            """A stable path (a symlink to the current pseudo-terminal), like a udev name."""
        else:
            from nmsid.testing.fakes import protocol_leptrinoemu  # noqa: PLC0415
            protocol_leptrinoemu.register()
            self._name = f"sensor{next(_names)}"
            self.port = f"leptrinoemu://{self._name}"
            _INPROCESS[self._name] = self
        self._unplugged = False
        self._new_pty()
        self.replugs = 0

    def _new_pty(self):
        """A new transport behind the same ``port`` (named for the POSIX case)."""
        self.transport = (_PtyTransport(self.port) if self.transport_kind == "pty"
                          else InProcessTransport())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="leptrino-emulator",
                                        daemon=True)

    # -- control ----------------------------------------------------------------------
    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self.transport.close()
        if self.transport_kind == "pty":
            try:
                os.unlink(self.port)
                os.rmdir(self._dir)
            except OSError:
                pass
        else:
            _INPROCESS.pop(self._name, None)

    def inject(self, data: bytes):
        with self._lock:
            self._send(bytes(data))

    def stall(self):
        self._stalled = True

    def unplug(self):
        """Like pulling the USB cable: the master side goes away."""
        self._unplugged = True
        self._stop.set()
        self._thread.join(timeout=2)
        self.transport.close()

    def replug(self):
        """The sensor is back (after :meth:`unplug`): a new pseudo-terminal at ``port``.

        Like a re-enumerated USB device: not streaming, fresh receive state; a handle opened
        before the glitch stays dead, only a newly opened port reaches the sensor.
        """
        with self._lock:
            self._streaming = self._stalled = False
            self._out.clear()
            self._rx.clear()
        self._new_pty()
        self._unplugged = False
        self.replugs += 1
        self._thread.start()

    @property
    def streaming(self) -> bool:
        return self._streaming

    # -- protocol -------------------------------------------------------------------
    def _run(self):
        while not self._stop.is_set():
            try:
                data = self.transport.recv(0.002)
            except (OSError, ValueError):
                return
            if data:
                self._receive(data)
            self._stream()
            self._flush()

    def _receive(self, data: bytes):
        self._rx += data
        while True:
            start = self._rx.find(bytes([DLE, STX]))
            if start < 0:
                self._rx.clear()
                return
            del self._rx[:start]
            # find the terminating DLE ETX (not a doubled DLE)
            payload: bytearray | None
            i, payload, end = 2, bytearray(), None
            while i < len(self._rx):
                b = self._rx[i]
                if b == DLE:
                    if i + 1 >= len(self._rx):
                        break
                    nxt = self._rx[i + 1]
                    if nxt == DLE:
                        payload.append(DLE)
                        i += 2
                        continue
                    if nxt == ETX:
                        end = i + 2
                        break
                    # lone DLE (e.g. DLE STX restart): drop the broken frame, resync
                    self.bad_commands += 1
                    del self._rx[:i]
                    payload = None
                    break
                payload.append(b)
                i += 1
            if payload is None:
                continue
            if end is None or end >= len(self._rx):
                return  # incomplete
            check = self._rx[end]
            del self._rx[:end + 1]
            expected = ETX
            for b in payload:
                expected ^= b
            if check != expected or len(payload) < 4 or payload[0] != len(payload):
                self.bad_commands += 1
                self._send(bytes([DLE, NAK]))
                continue
            self._command(payload[2])

    def _command(self, cmd: int):
        self.commands.append(cmd)
        if self.nak_next > 0:
            self.nak_next -= 1
            self._send(bytes([DLE, NAK]))
            return
        if cmd == 0x32 and self.nak_start > 0:
            self.nak_start -= 1
            self._send(bytes([DLE, NAK]))
            return
        result = self.error_result.get(cmd, 0)
        if result:
            self._send(_frame(bytes([4, 0xFF, cmd, result])))
            return
        if cmd == 0xB6:  # 5.3: LEN 8, setting, 3 reserved bytes
            self._reply(_frame(bytes([8, 0xFF, cmd, 0, self.filter_code, 0, 0, 0])))
        elif cmd == 0x2A:
            data = (self.model.encode().ljust(16, b"\0") + self.serial.encode().ljust(8, b"\0")
                    + self.firmware.encode().ljust(4, b"\0"))
            if self.rate_text is not None:  # older firmware: no rate field at all
                data += self.rate_text.encode()[:6].ljust(6, b"\0")
            self._reply(_frame(bytes([4 + len(data), 0xFF, cmd, 0]) + data))
        elif cmd == 0x2B:
            data = struct.pack("<6f", *self.rated)
            self._reply(_frame(bytes([4 + len(data), 0xFF, cmd, 0]) + data))
        elif cmd == 0x30:
            self._send(self._record(time.monotonic() - self._t0, cmd))
        elif cmd == 0x32:  # 6.2: the response first, then the records
            with self._lock:
                self._send(_frame(bytes([4, 0xFF, cmd, 0])))
                self._streaming, self._stalled = True, False
                self._t0, self._stream_sent = time.monotonic(), 0
        elif cmd == 0x33:
            with self._lock:
                self._streaming = False
            self._reply(_frame(bytes([4, 0xFF, cmd, 0])))
        else:
            self._send(_frame(bytes([4, 0xFF, cmd, 0x02])))  # undefined command

    def _record(self, t: float, cmd: int = 0x32) -> bytes:
        wrench = self.wrench_fn(t)
        raw = [max(-FULL_SCALE, min(FULL_SCALE, int(round(w / r * 10000.0))))
               for w, r in zip(wrench, self.rated, strict=True)]
        status = int(self.status_fn(t)) & 0xFF
        reserved = 0x09C4
        if self.reserved_bits_random:  # 6.1: bits 3-7 and the 2 bytes after Mz reserved
            status = (status & 0x07) | (self.rng.randrange(256) & 0xF8)
            reserved = self.rng.randrange(65536)
        data = struct.pack("<6hHBB", *raw, reserved, status, 0)
        return _frame(bytes([4 + len(data), 0xFF, cmd, self.data_result]) + data)

    def _stream(self):
        with self._lock:
            if not self._streaming or self._stalled:
                return
            due = int((time.monotonic() - self._t0) * self.rate_Hz) - self._stream_sent
            for _ in range(max(0, min(due, 2000))):
                t = self._stream_sent / self.rate_Hz
                frame = bytearray(self._record(t))
                self._stream_sent += 1
                self.frames_sent += 1
                if self.corrupt_every and self.frames_sent % self.corrupt_every == 0:
                    frame[-1] ^= 0x5A
                if self.garbage_every and self.frames_sent % self.garbage_every == 0:
                    n_garbage = self.rng.randint(1, 9)
                    self._send(bytes(self.rng.randrange(256) for _ in range(n_garbage)))
                self._send(bytes(frame))

    def _reply(self, frame: bytes):
        if self.corrupt_replies > 0:
            self.corrupt_replies -= 1
            frame = frame[:-1] + bytes([frame[-1] ^ 0xA5])
        self._send(frame)

    def _send(self, data: bytes):
        if len(self._out) > 256 * 1024:
            self.frames_dropped += 1
            return
        self._out += data

    def _flush(self):
        while self._out:
            n = self.rng.randint(1, 7) if self.fragment else len(self._out)
            try:
                written = self.transport.send(bytes(self._out[:n]))
            except BlockingIOError:
                return
            except OSError:
                self._out.clear()
                return
            del self._out[:written]
            if self.fragment:
                time.sleep(0.00005 if self.rng.random() < 0.2 else 0)
