"""Hasomed RehaStim2 over ScienceMode2: biphasic pulses streamed by the host.

The device (8 channels, two current sources, 0 .. 130 mA, 20 .. 500 us, biphasic
charge-balanced pulses: SM2 1.2, Table 1) is driven in the continuous channel list mode
(SM2 1.3): ``arm`` sends InitChannelListMode with the extensor and flexor channels at the
configured pulse rate; ``start`` streams one StartChannelListMode update per main interval,
each carrying the envelope's current at that pulse (amplitude modulation at a fixed width);
the trial ends with StopChannelListMode. A link thread reads every packet, answers the
device's Init (SM2 4.1), sends the Watchdog (SM2 4.1) whenever nothing was sent for
:data:`~nmsid.drivers.rehastim2_link.KEEPALIVE_S` (< the 1.2 s WatchdogTimeout of SM2 2.3), and
turns a StimulationError (emergency switch, electrode error, module error: SM2 4.3) into the ERROR
state the interlock trips on.

Safety, by construction: each update's current is the envelope rounded down to the device's
2 mA step (user manual 2.5c, 4.1: "0-130 mA in 65 steps"; :func:`to_steps_mA`), the envelope was
already checked against its ceilings (:class:`~nmsid.drivers.interfaces.CheckedWaveform`), and
:meth:`_pulse_data` refuses any current above the driver's own ceilings before a byte is written
(:class:`~nmsid.drivers.interfaces.CurrentLimitError`). Charge balance is the device's:
SM2 1.2 (Figure 2) fixes both phases at the same current and width, plus an active
short-cut at the end of each pulse.

Acknowledgements: each update waits for its predecessor's response (SM2 5.1 -8 busy: "wait
for the response packet"; 2.3 MaxResponseTime 100 ms). An update the device answers busy
(-8) or with a transfer error (-1, SM2 4.3) was not applied: it is counted and the next one
replaces it (SM2 1.3: updates may be skipped), never a fault. The stop is a request
confirmed by the device (:meth:`Rehastim2Stimulator.stop_now`, SM2 5.3); an unconfirmed
stop withholds the keep-alive so the device's own watchdog ends the output (SM2 5.2).

Time base: ScienceMode2 has no trigger output, so ``capabilities().hardware_trigger`` is
False; the engine starts the acquisition from the host just before ``start``, and the
trial's ``stimulation_json`` records the host time from that start to the first update's
acknowledgement (``onset_ack_s``).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from nmsid.drivers import rehastim2_protocol as sm2
from nmsid.drivers.errors import DeviceError, DeviceNotFound, StimulatorSettingError
from nmsid.drivers.interfaces import (
    BIPHASIC_PULSES,
    CheckedWaveform,
    CurrentLimitError,
    StimulatorCapabilities,
    StimulatorState,
    StimulatorStatus,
    Waveshape,
)
from nmsid.drivers.rehastim2_link import Sm2Link, _open_serial

log = logging.getLogger(__name__)

CONNECT_TIMEOUT_S = 2.5
"""Wait for the device's Init this long. A device still attached to a previous connection
sends Init only after its WatchdogTimeout (1.2 s) and then every InitRepetitionTime
(0.5 s) (SM2 2.3, 5.2): 1.2 + 2 x 0.5 s, with margin."""
SUMMARY_FORMAT = "nmsid-stimulation-1"
STEP_MA = 2
"""The current resolution: RehaStim2 user manual 2.5c, 4.1 "0-130 mA in 65 steps" (the
ScienceMode2 README: 2 mA steps). Currents are rounded DOWN to a step, so an odd value never
reaches a device that might round it up above its ceiling."""
UPDATE_ACK_WAIT_S = 2 * sm2.MAX_RESPONSE_S
"""An update unanswered this long is counted as unanswered and the next one goes out (SM2
2.3: MaxResponseTime 100 ms; x 2 for a host thread scheduled late)."""


def to_steps_mA(current_mA) -> np.ndarray:
    """Currents rounded down to the device's :data:`STEP_MA` (whole steps, ints)."""
    c = np.asarray(current_mA, dtype=float)
    return (STEP_MA * np.floor(c / STEP_MA + 1e-9)).astype(int)


class Rehastim2Stimulator(Sm2Link):
    """The RehaStim2 as a :class:`~nmsid.drivers.interfaces.Stimulator` and a
    :class:`~nmsid.drivers.interfaces.HostStreamedStimulator`.

    Parameters
    ----------
    port : str
        The FTDI serial port (``COM5``, ``/dev/ttyUSB0``).
    ceiling_ext_mA, ceiling_flex_mA : float
        The session's ceilings; no update above them is ever written.
    extensor_channel, flexor_channel : int
        RehaStim2 channels 1 .. 8 (SM2 Table 3).
    pulse_rate_Hz : float
        Pulses per second per channel (SM2 Table 1: 1 .. 50 Hz; the main interval is
        1 ms + k x 0.5 ms, SM2 4.3).
    pulse_width_us : int
        Width of each phase, 20 .. 500 us (SM2 4.3).
    open_port : callable(port) -> serial-like, optional
        How the port is opened (the fake in fake mode); default pyserial at 460800 8E1.
    clock, sleep : callables, optional
        Time source and wait (the fake bench's in fake mode).
    """

    def __init__(self, port: str, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                 extensor_channel: int = 1, flexor_channel: int = 2,
                 pulse_rate_Hz: float = 40.0, pulse_width_us: int = 300,
                 open_port: Callable | None = None, clock: Callable[[], float] | None = None,
                 sleep: Callable[[float], None] | None = None):
        if extensor_channel == flexor_channel:
            raise StimulatorSettingError(f"RehaStim2: extensor_channel and flexor_channel "
                                         f"are both {extensor_channel}; they must differ")
        try:
            sm2.main_interval_code(pulse_rate_Hz)
            sm2.start_clm_data([(int(pulse_width_us), 0)])
        except ValueError as exc:
            raise StimulatorSettingError(f"RehaStim2: {exc}") from None
        if not 1.0 <= pulse_rate_Hz <= sm2.MAX_RATE_HZ:
            raise StimulatorSettingError(f"RehaStim2: pulse_rate_Hz {pulse_rate_Hz:g}: valid "
                                         "1 .. 50 Hz (SM2 Table 1)")
        for name, c in (("ceiling_ext_mA", ceiling_ext_mA), ("ceiling_flex_mA", ceiling_flex_mA)):
            if not (math.isfinite(c) and 0 < c <= sm2.MAX_CURRENT_MA):
                raise StimulatorSettingError(f"RehaStim2: {name} = {c!r}: valid > 0 and "
                                             f"<= {sm2.MAX_CURRENT_MA} mA (SM2 Table 1)")
        self.port = port
        self.ceilings = {extensor_channel: float(ceiling_ext_mA),
                         flexor_channel: float(ceiling_flex_mA)}
        self._stream_ceilings = dict(self.ceilings)
        """The ceilings of the open stream (open_stream may lower the driver's)."""
        self.extensor_channel, self.flexor_channel = extensor_channel, flexor_channel
        self.channels = tuple(sorted((extensor_channel, flexor_channel)))
        self.pulse_rate_Hz, self.pulse_width_us = float(pulse_rate_Hz), int(pulse_width_us)
        self._open_port = open_port or _open_serial
        self.clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self._ser = None
        self._decoder = sm2.Decoder()
        self._wlock = threading.Lock()
        self._lock = threading.RLock()
        self._number = 0
        self._last_sent = 0.0
        self._acks: dict[int, sm2.Packet] = {}
        self._silent = False
        """Set when a stop could not be confirmed: nothing more is written, so the device's
        watchdog ends the output (SM2 5.2); connect() clears it."""
        self._update_numbers: dict[int, int] = {}   # packet number -> index in _sent
        self._pending_update: tuple[int, float] | None = None
        self._delivered: list[int] = []
        self._busy = self._transfer_errors = self._unanswered = 0
        self._waiting: set[int] = set()
        self._ack_cv = threading.Condition(self._lock)
        self._error = ""
        self._state = StimulatorState.DISCONNECTED
        self._link: threading.Thread | None = None
        self._link_stop = threading.Event()
        self._stream: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._queue: collections.deque[tuple[int, int]] = collections.deque()
        self._streaming_open = False
        self._trial_pulses: list[tuple[int, int]] = []
        self._sent: list[tuple[int, int]] = []
        self._sent_index: list[int] = []
        self._skipped = 0
        self._ack_errors: list[str] = []
        self._onset_ack_s: float | None = None
        self._t_start_call = 0.0
        self._ended_by = ""
        self._loaded: CheckedWaveform | None = None

    # -- connection ------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, answer the device's Init (SM2 4.1, 3.5), start the link thread."""
        self._close_link()
        try:
            self._ser = self._open_port(self.port)
        except Exception as exc:
            raise DeviceNotFound(f"RehaStim2: cannot open serial port {self.port!r} "
                                 f"({type(exc).__name__}: {exc}); check the USB cable, the "
                                 "FTDI driver and that ScienceMode2 is selected on the "
                                 "device's start screen (SM2 1.5, 2.1)") from None
        self._decoder = sm2.Decoder()
        self._silent = False
        deadline = self.clock() + CONNECT_TIMEOUT_S
        init = None
        problem = ""
        while init is None and self.clock() < deadline:
            try:
                packets = self._read_packets()
            except Exception as exc:  # the port failed at once: reported below, one line
                problem = f" ({type(exc).__name__}: {exc})"
                break
            for pkt in packets:
                if pkt.command == sm2.INIT:
                    init = pkt
            if init is None:
                self._sleep(0.01)
        if init is None:
            self._close_port()
            raise DeviceNotFound(f"RehaStim2 on {self.port}: no Init packet within "
                                 f"{CONNECT_TIMEOUT_S:g} s{problem} (ScienceMode2 2.3 "
                                 "InitRepetitionTime 0.5 s); is ScienceMode2 started on the "
                                 "device?")
        self._write(sm2.INIT_ACK, bytes((0,)), number=init.number)   # SM2 4.1 InitAck
        with self._lock:
            self._error, self._acks = "", {}
            self._state = StimulatorState.IDLE
        self._link_stop.clear()
        self._link = threading.Thread(target=self._link_loop, name="rehastim2-link",
                                      daemon=True)
        self._link.start()
        mode = self.stimulation_mode()
        if mode != 0 and not self._confirm_stop():   # left running by a previous program
            raise DeviceError(self._error)

    def capabilities(self) -> StimulatorCapabilities:
        return StimulatorCapabilities(
            n_channels=sm2.N_CHANNELS, max_current_mA=float(sm2.MAX_CURRENT_MA),
            resolution_mA=float(STEP_MA), output_rate_Hz=self.pulse_rate_Hz,
            model="Hasomed RehaStim2", waveshape=self.waveshape(), hardware_trigger=False)

    def waveshape(self) -> Waveshape:
        return Waveshape(kind=BIPHASIC_PULSES, pulse_rate_Hz=self.pulse_rate_Hz,
                         pulse_width_us=float(self.pulse_width_us),
                         interphase_us=float(sm2.INTERPHASE_US), modulation="amplitude")

    def disconnect(self) -> None:
        self.stop_now()
        self._close_link()
        with self._lock:
            self._state = StimulatorState.DISCONNECTED

    def stimulation_mode(self) -> int:
        """GetStimulationMode (SM2 4.2): 0 start, 1 initialized, 2 started."""
        ack = self._request(sm2.GET_STIM_MODE)
        return ack.data[1] if len(ack.data) > 1 else 0

    # -- one trial ---------------------------------------------------------------------------
    def load(self, waveform: CheckedWaveform) -> None:
        """Sample the envelopes at each pulse and keep the per-pulse currents (2 mA steps,
        rounded down, so never above the envelope and so never above its ceiling)."""
        self._check_usable("load")
        for ch, ceiling in ((self.extensor_channel, waveform.ceiling_ext_mA),
                            (self.flexor_channel, waveform.ceiling_flex_mA)):
            if ceiling > self.ceilings[ch] + 1e-9:
                raise CurrentLimitError(
                    f"waveform ceiling {ceiling:g} mA on RehaStim2 channel {ch} is above the "
                    f"driver's {self.ceilings[ch]:g} mA; nothing was sent")
        n = math.floor(waveform.duration_s * self.pulse_rate_Hz + 1e-9)
        k = np.minimum((np.arange(n) / self.pulse_rate_Hz * waveform.fs_Hz + 1e-9)
                       .astype(np.int64), waveform.n_samples - 1)
        ext = to_steps_mA(np.asarray(waveform.I_ext_mA)[k])
        flex = to_steps_mA(np.asarray(waveform.I_flex_mA)[k])
        pulses = list(zip(ext.tolist(), flex.tolist(), strict=True))
        for e, f in pulses:                  # by construction; checked once more
            self._pulse_data(e, f)
        with self._lock:
            self._trial_pulses = pulses
            self._loaded = waveform
            self._state = StimulatorState.LOADED

    def arm(self) -> None:
        """InitChannelListMode for the two channels at the pulse rate (SM2 4.3); an open
        stream is armed already (:meth:`open_stream`)."""
        self._check_usable("arm")
        with self._lock:
            if self._streaming_open and self._state is StimulatorState.ARMED:
                return
        if self.stimulation_mode() != 0 and not self._confirm_stop():
            raise DeviceError(self._error)
        self._request(sm2.INIT_CLM, sm2.init_clm_data(self.channels, self.pulse_rate_Hz))
        with self._lock:
            self._state = StimulatorState.ARMED

    def start(self) -> None:
        """Stream the loaded pulses, one StartChannelListMode per main interval."""
        with self._lock:
            if self._state is not StimulatorState.ARMED:
                raise DeviceError(f"RehaStim2: start() in state {self._state.value}; "
                                  "load() and arm() first")
            if not self._streaming_open:     # a stream keeps what write_stream queued
                self._queue = collections.deque(self._trial_pulses)
            self._reset_trial_counts()
            self._onset_ack_s, self._ended_by = None, ""
            self._streaming_open = False
            self._state = StimulatorState.RUNNING
        self._t_start_call = time.monotonic()
        self._start_stream_thread()

    def stop_now(self) -> None:
        """StopChannelListMode now, confirmed (SM2 4.3, 5.3). Thread-safe, idempotent,
        never raises.

        The stop goes out at once; the stream thread is then ended and GetStimulationMode
        asked until the device answers mode 0, resending the stop while it does not (a lost
        packet, a -1 transfer error: SM2 4.3, 5.2). If the device has not confirmed within
        :data:`~nmsid.drivers.rehastim2_link.STOP_CONFIRM_S`, nothing more is written, the
        keep-alive included, so the device's watchdog stops it within its 1.2 s WatchdogTimeout of
        the last packet it received (SM2 2.3, 5.2), and the driver reports that in one line
        (ERROR)."""
        self._stream_stop.set()
        with self._lock:
            self._queue.clear()
            if not self._ended_by and self._state is StimulatorState.RUNNING:
                self._ended_by = "stop_now"
            if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED,
                               StimulatorState.LOADED):
                self._state = StimulatorState.STOPPED
        if self._ser is None or self._silent:
            return
        try:
            self._write(sm2.STOP_CLM)            # first, before anything else
        except Exception as exc:   # link gone: the device's watchdog stops it (SM2 5.2)
            message = (f"RehaStim2 stop could not be sent ({exc}); the device stops by its "
                       f"watchdog within {sm2.WATCHDOG_TIMEOUT_S:g} s (ScienceMode2 5.2)")
            log.error(message)
            with self._lock:
                self._error = self._error or message
                self._state = StimulatorState.ERROR
            return
        t = self._stream
        if t is not None and t is not threading.current_thread():
            t.join(timeout=1.0)
        self._confirm_stop()

    def status(self) -> StimulatorStatus:
        ser = self._ser
        if ser is not None and not self._error:
            try:      # ask the port itself: a lost USB link fails here at once
                _ = ser.in_waiting
            except Exception as exc:
                with self._lock:
                    self._error = f"RehaStim2 USB link lost ({type(exc).__name__}: {exc})"
                    self._state = StimulatorState.ERROR
        with self._lock:
            st = self._state
            running = st is StimulatorState.RUNNING
            return StimulatorStatus(state=st, output_active=running, error=self._error,
                                    sample_index=len(self._sent) if running else -1)

    # -- host-streamed capability (closed loop) ------------------------------------------------
    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float,
                    update_Hz: float) -> float:
        """Initialise the channel list (armed); updates written from now on stream at the
        pulse rate from :meth:`start` on. Returns the pulse rate."""
        for ch, c in ((self.extensor_channel, ceiling_ext_mA),
                      (self.flexor_channel, ceiling_flex_mA)):
            if c > self.ceilings[ch] + 1e-9:
                raise CurrentLimitError(f"stream ceiling {c:g} mA on channel {ch} is above "
                                        f"the driver's {self.ceilings[ch]:g} mA")
        self._stream_ceilings.update({self.extensor_channel: float(ceiling_ext_mA),
                                      self.flexor_channel: float(ceiling_flex_mA)})
        with self._lock:
            self._streaming_open = False
        self.arm()
        with self._lock:
            self._queue.clear()
            self._reset_trial_counts()
            self._streaming_open = True
        return self.pulse_rate_Hz

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        ext, flex = to_steps_mA(I_ext_mA), to_steps_mA(I_flex_mA)   # user manual 4.1
        if len(ext) != len(flex):
            raise CurrentLimitError("I_ext_mA and I_flex_mA must have the same length")
        lim = self._stream_ceilings
        for name, arr, ch in (("I_ext_mA", I_ext_mA, self.extensor_channel),
                              ("I_flex_mA", I_flex_mA, self.flexor_channel)):
            a = np.asarray(arr, float)
            if a.size and (not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > lim[ch]):
                raise CurrentLimitError(f"{name} outside 0 .. {lim[ch]:g} mA (or not finite); "
                                        "nothing was sent")
        with self._lock:
            self._queue.extend(zip(ext.tolist(), flex.tolist(), strict=True))

    def stream_space(self) -> int:
        with self._lock:
            return max(0, int(self.pulse_rate_Hz) - len(self._queue))

    def close_stream(self) -> None:
        with self._lock:
            self._streaming_open = False
        t = self._stream
        if t is not None:
            t.join(timeout=2.0 + len(self._queue) / self.pulse_rate_Hz)
        self.stop_now()

    # -- what was delivered ---------------------------------------------------------------------
    def delivery_summary(self) -> dict | None:
        """The pulses of the last trial: per channel, the current of every update the device
        acknowledged (``pulse_index``: each one's slot, k / pulse_rate_Hz s after onset), the
        width, the charge per phase, and the updates skipped because the host fell behind
        the time base (plain JSON types)."""
        with self._lock:
            sent, index = list(self._sent), list(self._sent_index)
            got = sorted(set(self._delivered))
            errors, skipped = list(self._ack_errors), self._skipped
            onset, ended = self._onset_ack_s, self._ended_by
            busy, transfer, unanswered = self._busy, self._transfer_errors, self._unanswered
        if self._loaded is None and not sent:
            return None
        delivered = [sent[i] for i in got]
        channels = {}
        for name, idx, ch in (("extensor", 0, self.extensor_channel),
                              ("flexor", 1, self.flexor_channel)):
            amps = [p[idx] for p in delivered]
            peak = max(amps, default=0)
            channels[name] = {
                "name": name, "channel": ch, "pulses_acknowledged": len(amps),
                "pulses_sent": len(sent), "pulse_current_mA": amps,
                "peak_current_mA": float(peak),
                "max_charge_per_phase_nC": float(peak * self.pulse_width_us),
                "net_charge_per_trial_uC": 0.0,
                "ceiling_mA": self.ceilings[ch]}
        return {"format": SUMMARY_FORMAT, "device": "rehastim2",
                "waveshape": self.waveshape().to_json(),
                "carrier_Hz_note": "a pulse device renders no carrier: the session's "
                                   "carrier_Hz is the protocol setting, not delivered",
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us,
                "charge_balanced": "by the device: equal biphasic phases (ScienceMode2 1.2)",
                "repeats_update": True,      # SM2 1.3: in force until the next update
                "updates_planned": len(self._trial_pulses), "updates_sent": len(sent),
                "updates_acknowledged": len(got), "update_errors": errors,
                "updates_skipped_late": skipped, "updates_busy": busy,
                "updates_transfer_error": transfer, "updates_unanswered": unanswered,
                "pulse_index": [index[i] for i in got],
                "onset_ack_s": onset, "ended_by": ended or "completed",
                "channels": channels}

    def describe(self) -> dict:
        return {"device": "Hasomed RehaStim2 (ScienceMode2)", "port": self.port,
                "extensor_channel": self.extensor_channel,
                "flexor_channel": self.flexor_channel,
                "ceiling_ext_mA": self.ceilings[self.extensor_channel],
                "ceiling_flex_mA": self.ceilings[self.flexor_channel],
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us,
                "trigger_output": "none (ScienceMode2 has none): acquisition host-started",
                "electrode_check": "the device tests the skin resistance before each pulse "
                                   "and stops with an electrode error (ScienceMode2 1.2, 4.3)",
                "state": self.status().state.value, "error": self._error}

    # -- internals ------------------------------------------------------------------------------
    def _pulse_data(self, I_ext: int, I_flex: int) -> bytes:
        """The StartChannelListMode data of one update; refuses a current above a ceiling."""
        by_ch = {self.extensor_channel: I_ext, self.flexor_channel: I_flex}
        for ch, cur in by_ch.items():
            if cur < 0 or cur > self.ceilings[ch] + 1e-9:
                raise CurrentLimitError(f"RehaStim2 channel {ch}: {cur} mA outside 0 .. "
                                        f"{self.ceilings[ch]:g} mA; nothing was sent")
        return sm2.start_clm_data([(self.pulse_width_us, by_ch[ch]) for ch in self.channels])

    def _start_stream_thread(self) -> None:
        self._stream_stop.clear()
        self._stream = threading.Thread(target=self._stream_loop, name="rehastim2-stream",
                                        daemon=True)
        self._stream.start()

    def _stream_loop(self) -> None:
        period = 1.0 / self.pulse_rate_Hz
        t0 = self.clock()
        k = 0
        try:
            while not self._stream_stop.is_set():
                self._await_update_ack()     # SM2 5.1 -8: the predecessor answered first
                with self._lock:
                    if self._queue:
                        e, f = self._queue.popleft()
                    elif self._streaming_open:
                        e = f = -1           # nothing queued in a stream: wait
                    else:
                        break
                if e < 0:
                    self._sleep(period / 4)
                    continue
                wait = t0 + k * period - self.clock()
                if wait > 0:
                    self._sleep(wait)
                elif not self._streaming_open and -wait > period:
                    # behind the trial's time base (a busy host): skip to the update that
                    # is due now, so the delivered amplitude keeps the recorded time axis;
                    # the skipped updates are counted in the delivery summary
                    late = min(int(-wait / period), len(self._queue))
                    with self._lock:
                        for _ in range(late):
                            e, f = self._queue.popleft()
                        self._skipped += late
                    k += late
                if self._stream_stop.is_set():
                    break
                data = self._pulse_data(e, f)
                with self._lock:             # registered before its ack can be handled
                    if self._error:
                        break
                    number = self._write(sm2.START_CLM, data)
                    self._update_numbers[number] = len(self._sent)
                    self._pending_update = (number, time.monotonic())
                    self._sent.append((e, f))
                    self._sent_index.append(k)
                k += 1
        except Exception as exc:   # a lost link: the watchdog stops the device (SM2 5.2)
            with self._lock:
                self._error = self._error or (f"RehaStim2 link lost while stimulating "
                                              f"({type(exc).__name__}: {exc})")
                self._state = StimulatorState.ERROR
            return
        if not self._stream_stop.is_set():
            self._await_update_ack()         # the last update's acknowledgement
            with self._lock:
                self._ended_by = self._ended_by or "completed"
            self.stop_now()

    def _await_update_ack(self) -> None:
        """Wait for the outstanding update's response, at most :data:`UPDATE_ACK_WAIT_S`."""
        with self._lock:
            while self._pending_update is not None and not self._error \
                    and not self._stream_stop.is_set():
                if time.monotonic() - self._pending_update[1] > UPDATE_ACK_WAIT_S:
                    self._unanswered += 1    # lost on the line: the next update replaces it
                    self._pending_update = None
                    break
                self._ack_cv.wait(0.005)

    def _reset_trial_counts(self) -> None:
        self._sent, self._sent_index, self._ack_errors = [], [], []
        self._delivered, self._update_numbers, self._pending_update = [], {}, None
        self._skipped = self._busy = self._transfer_errors = self._unanswered = 0

    def _check_usable(self, what: str) -> None:
        with self._lock:
            if self._state is StimulatorState.DISCONNECTED:
                raise DeviceError(f"RehaStim2: {what}() before connect()")
            if self._error:
                raise DeviceError(self._error)
