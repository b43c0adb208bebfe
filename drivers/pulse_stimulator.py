"""What the host-streamed pulse stimulators share: Hasomed's RehaStim2 (ScienceMode2,
:mod:`nmsid.drivers.rehastim2`) and P24 / RehaMove3 (ScienceMode4,
:mod:`nmsid.drivers.sciencemode4`).

Both stream one update per pulse period from a host thread, and both need the same
discipline, kept here once; each device's documented specifics (its protocol, current step,
ranges, stop command, how the stop is confirmed and what ends the output when it is not)
stay in its own module, cited there.

- **Currents rounded down** to the device's step (:func:`steps_down_mA`): never up, so a
  current never reaches a device that might round it up past its ceiling.
- **Ceilings**: a waveform's or a stream's ceiling above the driver's is refused
  (:meth:`PulseStimulator._check_ceilings`), every pulse is checked once more before a
  byte is written (the driver's ``_check_pulse``), and a stream's updates against the
  stream's ceilings (:meth:`PulseStimulator.write_stream`).
- **Update pacing** (:meth:`PulseStimulator._stream_loop`): update k goes out k /
  ``pulse_rate_Hz`` after the start; a host behind the time base by more than a period
  skips to the update due now (counted, ``updates_skipped_late``), so the delivered
  amplitude keeps the recorded time axis; a stream (closed loop) waits for updates and
  its time base moves by the wait. How an update is sent and acknowledged (busy replies,
  late answers) is the driver's ``_send_update``.
- **The stop** (:meth:`PulseStimulator.stop_now`): the stream ends and its queue is
  dropped at once, the driver's stop command goes out, then the device is asked until it
  confirms, the stop resent meanwhile (:meth:`PulseStimulator._confirm_stopped`).
  Unconfirmed within the driver's ``STOP_CONFIRM_S``: nothing more is written, the
  keep-alive included, so the device's own timeout ends the output (the driver's
  ``fallback``), the driver goes to ERROR (the interlock trips) and the operator reads one
  line.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from nmsid.drivers.errors import DeviceError, DeviceNotFound
from nmsid.drivers.interfaces import (
    BIPHASIC_PULSES,
    CheckedWaveform,
    CurrentLimitError,
    StimulatorState,
    StimulatorStatus,
    Waveshape,
)

SUMMARY_FORMAT = "nmsid-stimulation-1"


def steps_down_mA(current_mA, step_mA: float) -> np.ndarray:
    """Currents rounded DOWN to whole steps of ``step_mA`` (floats)."""
    c = np.asarray(current_mA, dtype=float)
    return step_mA * np.floor(c / step_mA + 1e-9)


class PulseStimulator:
    """The shared part of a host-streamed pulse stimulator (module docstring).

    A driver sets, in its ``__init__``, :attr:`title`, :attr:`log`, :attr:`step_mA`,
    :attr:`fallback`, :attr:`operator_action`, :attr:`stop_confirm_s` and calls
    :meth:`_init_pulses`; it implements ``_check_pulse``, ``_send_update``,
    ``_write_stop``, ``_confirm_stop_now`` and ``_reset_device_counts``.
    """

    title: str
    """The device's name in messages (``Hasomed P24``, ``RehaStim2``)."""
    log: logging.Logger
    step_mA: float
    """The device's current resolution."""
    stop_confirm_s: float
    fallback: str
    """What ends the output when the stop is not confirmed (the device's own timeout)."""
    operator_action: str
    """What the operator is told to do then."""
    interphase_us: int
    _open_port: Callable[[str], Any]
    _t0: float
    """The clock time of the stream's slot 0 (update k is due at ``_t0 + k / rate``)."""
    _ser: Any
    _silent: bool
    _link: threading.Thread | None

    def _init_pulses(self, port: str, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                     extensor_channel: int, flexor_channel: int, pulse_rate_Hz: float,
                     pulse_width_us: int, clock: Callable[[], float] | None,
                     sleep: Callable[[float], None] | None) -> None:
        self.port = port
        self.extensor_channel, self.flexor_channel = extensor_channel, flexor_channel
        self.ceilings = {extensor_channel: float(ceiling_ext_mA),
                         flexor_channel: float(ceiling_flex_mA)}
        self._stream_ceilings = dict(self.ceilings)
        """The ceilings of the open stream (open_stream may lower the driver's)."""
        self.pulse_rate_Hz, self.pulse_width_us = float(pulse_rate_Hz), int(pulse_width_us)
        self.clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self._ser = None
        self._wlock = threading.Lock()
        self._lock = threading.RLock()
        self._silent = False
        """Set when a stop could not be confirmed: nothing more is written, so the device's
        own timeout ends the output; connect() clears it."""
        self._error = ""
        self._state = StimulatorState.DISCONNECTED
        self._link = None
        self._link_stop = threading.Event()
        self._stream: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._queue: collections.deque[tuple[float, float]] = collections.deque()
        self._streaming_open = False
        self._trial: list[tuple[float, float]] = []
        self._loaded: CheckedWaveform | None = None
        self._ended_by = ""
        self.stop_log: list[tuple[float, str]] = []
        """(clock time, what) of each stop: asked, confirmed or unconfirmed (tests, bench)."""
        self._reset_counts()

    # -- the device-specific part --------------------------------------------------------------
    def _check_pulse(self, I_ext_mA: float, I_flex_mA: float) -> None:
        """Refuse a pulse above a ceiling (CurrentLimitError) before it is encoded."""
        raise NotImplementedError

    def _send_update(self, k: int, I_ext_mA: float, I_flex_mA: float) -> bool:
        """Write update ``k`` (slot k / pulse_rate_Hz) and record it; False ends the
        stream (a stop or an error came first)."""
        raise NotImplementedError

    def _write_stop(self) -> None:
        """Write the device's stop command now (raises if it cannot be written)."""
        raise NotImplementedError

    def _confirm_stop_now(self) -> None:
        """Confirm the stop just written (:meth:`_confirm_stopped`)."""
        raise NotImplementedError

    def _reset_device_counts(self) -> None:
        """The driver's own per-trial counters."""

    def _steps(self, current_mA) -> np.ndarray:
        """Currents rounded down to the device's step (:func:`steps_down_mA`)."""
        return steps_down_mA(current_mA, self.step_mA)

    def _before_update(self) -> None:
        """Before the next update is taken from the queue (e.g. its predecessor's answer)."""

    def _idle(self) -> None:
        """While a stream waits for updates, and between updates (e.g. a keep-alive)."""

    def _after_last_update(self) -> None:
        """After the last update of a completed trial, before the stop."""

    # -- one trial ------------------------------------------------------------------------------
    def _check_usable(self, what: str) -> None:
        with self._lock:
            if self._state is StimulatorState.DISCONNECTED:
                raise DeviceError(f"{self.title}: {what}() before connect()")
            if self._error:
                raise DeviceError(self._error)

    def _check_ceilings(self, what: str, ceiling_ext_mA: float, ceiling_flex_mA: float
                        ) -> None:
        for ch, c in ((self.extensor_channel, ceiling_ext_mA),
                      (self.flexor_channel, ceiling_flex_mA)):
            if c > self.ceilings[ch] + 1e-9:
                raise CurrentLimitError(f"{what} ceiling {c:g} mA on {self.title} channel "
                                        f"{ch} is above the driver's {self.ceilings[ch]:g} "
                                        "mA; nothing was sent")

    def pulses_of(self, waveform: CheckedWaveform) -> list[tuple[float, float]]:
        """Each pulse's currents: the envelopes at the pulse, rounded down to the step."""
        n = math.floor(waveform.duration_s * self.pulse_rate_Hz + 1e-9)
        k = np.minimum((np.arange(n) / self.pulse_rate_Hz * waveform.fs_Hz + 1e-9)
                       .astype(np.int64), waveform.n_samples - 1)
        ext = self._steps(np.asarray(waveform.I_ext_mA)[k])
        flex = self._steps(np.asarray(waveform.I_flex_mA)[k])
        return list(zip(ext.tolist(), flex.tolist(), strict=True))

    def load(self, waveform: CheckedWaveform) -> None:
        """Keep the per-pulse currents (rounded down, so never above the envelope and so
        never above its ceiling; each checked once more)."""
        self._check_usable("load")
        self._check_ceilings("waveform", waveform.ceiling_ext_mA, waveform.ceiling_flex_mA)
        pulses = self.pulses_of(waveform)
        for e, f in pulses:                   # by construction; checked once more
            self._check_pulse(e, f)
        with self._lock:
            self._trial, self._loaded = pulses, waveform
            self._state = StimulatorState.LOADED

    def start(self) -> None:
        """Stream the loaded pulses (or an open stream's), one update per pulse period."""
        with self._lock:
            if self._state is not StimulatorState.ARMED:
                raise DeviceError(f"{self.title}: start() in state {self._state.value}; "
                                  "load() and arm() first")
            if not self._streaming_open:      # a stream keeps what write_stream queued
                self._queue = collections.deque(self._trial)
            self._reset_counts()              # a stream runs until close_stream (or a stop)
            self._state = StimulatorState.RUNNING
        self._t_start_call = time.monotonic()
        self._stream_stop.clear()
        self._stream = threading.Thread(target=self._stream_loop, daemon=True,
                                        name=f"{self.title.split()[-1].lower()}-stream")
        self._stream.start()

    def stop_now(self) -> None:
        """The stop, now, confirmed by the device (module docstring). Thread-safe,
        idempotent, never raises."""
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
        self.stop_log.append((self.clock(), "asked"))
        try:
            self._write_stop()                # first, before anything else
        except Exception as exc:
            self._go_silent(f"the stop could not be sent ({type(exc).__name__}: {exc})")
            return
        t = self._stream
        if t is not None and t is not threading.current_thread():
            t.join(timeout=1.0)
        self._confirm_stop_now()

    def status(self) -> StimulatorStatus:
        ser = self._ser
        if ser is not None and not self._error:
            try:      # ask the port itself: a lost USB link fails here at once
                _ = ser.in_waiting
            except Exception as exc:
                self._link_failed(exc)
        with self._lock:
            st = self._state
            running = st is StimulatorState.RUNNING
            return StimulatorStatus(state=st, output_active=running, error=self._error,
                                    sample_index=len(self._sent) if running else -1)

    def waveshape(self) -> Waveshape:
        return Waveshape(kind=BIPHASIC_PULSES, pulse_rate_Hz=self.pulse_rate_Hz,
                         pulse_width_us=float(self.pulse_width_us),
                         interphase_us=float(self.interphase_us), modulation="amplitude")

    # -- host-streamed capability (closed loop) ---------------------------------------------------
    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float,
                    update_Hz: float) -> float:
        """Arm; updates written from now on stream at the pulse rate from :meth:`start`
        on, until :meth:`close_stream`. Returns the pulse rate."""
        self._check_ceilings("stream", ceiling_ext_mA, ceiling_flex_mA)
        self._stream_ceilings.update({self.extensor_channel: float(ceiling_ext_mA),
                                      self.flexor_channel: float(ceiling_flex_mA)})
        with self._lock:
            self._streaming_open = False
        self.arm()
        with self._lock:
            self._queue.clear()
            self._reset_counts()
            self._streaming_open = True
        return self.pulse_rate_Hz

    def arm(self) -> None:
        raise NotImplementedError

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        lim = self._stream_ceilings
        for name, arr, ch in (("I_ext_mA", I_ext_mA, self.extensor_channel),
                              ("I_flex_mA", I_flex_mA, self.flexor_channel)):
            a = np.asarray(arr, float)
            if a.size and (not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > lim[ch]):
                raise CurrentLimitError(f"{name} outside 0 .. {lim[ch]:g} mA (or not "
                                        "finite); nothing was sent")
        ext, flex = self._steps(I_ext_mA), self._steps(I_flex_mA)
        if len(ext) != len(flex):
            raise CurrentLimitError("I_ext_mA and I_flex_mA must have the same length")
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
    def _reset_counts(self) -> None:
        self._sent: list[tuple[float, float]] = []
        self._sent_index: list[int] = []     # each update's slot k (k / rate after onset)
        self._skipped_late = 0
        self._ended_by = ""
        self._reset_device_counts()

    def _channel_summary(self, name: str, channel: int, amps: list, acknowledged: int,
                         sent: int) -> dict:
        peak = max(amps, default=0)
        return {"name": name, "channel": channel, "pulses_acknowledged": acknowledged,
                "pulses_sent": sent, "pulse_current_mA": amps,
                "peak_current_mA": float(peak),
                "max_charge_per_phase_nC": float(peak * self.pulse_width_us),
                "net_charge_per_trial_uC": 0.0, "ceiling_mA": self.ceilings[channel]}

    def _describe(self) -> dict:
        return {"port": self.port, "extensor_channel": self.extensor_channel,
                "flexor_channel": self.flexor_channel,
                "ceiling_ext_mA": self.ceilings[self.extensor_channel],
                "ceiling_flex_mA": self.ceilings[self.flexor_channel],
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us}

    # -- internals ------------------------------------------------------------------------------
    def _stream_loop(self) -> None:
        period = 1.0 / self.pulse_rate_Hz
        self._t0, k, waited = self.clock(), 0, False
        try:
            while not self._stream_stop.is_set():
                self._before_update()
                with self._lock:
                    if self._queue:
                        e, f = self._queue.popleft()
                    elif self._streaming_open:
                        e = f = -1.0          # nothing queued in a stream: wait
                    else:
                        break
                if e < 0:
                    self._sleep(period / 4)
                    self._idle()
                    waited = True
                    continue
                if waited:                    # a stream that waited: its time base moves
                    self._t0, waited = max(self._t0, self.clock() - k * period), False
                wait = self._t0 + k * period - self.clock()
                if wait > 0:
                    self._sleep(wait)
                elif -wait > period:
                    # behind the time base (a busy host): skip to the update due now, so
                    # the delivered amplitude keeps the recorded time axis; counted
                    with self._lock:
                        late = min(int(-wait / period), len(self._queue))
                        for _ in range(late):
                            e, f = self._queue.popleft()
                        self._skipped_late += late
                    k += late
                if self._stream_stop.is_set() or not self._send_update(k, e, f):
                    break
                self._idle()
                k += 1
        except Exception as exc:   # a lost link: the device's own timeout stops it
            self._link_failed(exc, "while stimulating")
            return
        if not self._stream_stop.is_set():
            self._after_last_update()
            with self._lock:
                self._ended_by = self._ended_by or "completed"
            self.stop_now()

    def _confirm_stopped(self, ask_stopped: Callable[[], bool], resend_stop: Callable[[], Any],
                         *, resend_first: bool, source: str) -> bool:
        """Ask ``ask_stopped`` until the device says it is stopped, calling ``resend_stop``
        before each ask after the first (and before the first too if ``resend_first``);
        unconfirmed within :attr:`stop_confirm_s`: :meth:`_go_silent`. ``source``: the
        documents' sections for the messages."""
        start = time.monotonic()
        deadline = start + self.stop_confirm_s
        resend = resend_first
        while time.monotonic() < deadline:
            try:
                if resend:
                    resend_stop()
                stopped = ask_stopped()
            except Exception as exc:          # the port itself failed
                self.log.warning("%s stop: %s", self.title, exc)
                break
            if stopped:
                self.stop_log.append((self.clock(), "confirmed"))
                if resend:
                    self.log.warning("%s: the stop was not confirmed at once (a packet lost or "
                                     "corrupted, or an answer late; %s); resent, now "
                                     "confirmed after %.0f ms", self.title, source,
                                     (time.monotonic() - start) * 1e3)
                return True
            resend = True
        self._go_silent(f"the device did not confirm the stop within "
                        f"{self.stop_confirm_s:g} s ({source})")
        return False

    def _go_silent(self, why: str) -> None:
        """Write nothing more, the keep-alive included, so the device's own timeout ends the
        output; ERROR, one line for the operator (logged once)."""
        self._silent = True
        self.stop_log.append((self.clock(), "unconfirmed"))
        message = (f"{self.title}: {why}; nmsid sends nothing more ({self.fallback}): "
                   f"{self.operator_action}")
        with self._lock:
            self.log.error(message)
            # a cause already reported (a lost USB link) stays first
            self._error = f"{self._error}; {message}" if self._error else message
            self._state = StimulatorState.ERROR
            self._notify()

    def _link_failed(self, exc: BaseException, when: str = "") -> None:
        with self._lock:
            self._error = self._error or (f"{self.title} USB link lost"
                                          f"{' ' + when if when else ''} "
                                          f"({type(exc).__name__}: {exc})")
            self._state = StimulatorState.ERROR
            self._notify()

    def _notify(self) -> None:
        """Wake the threads waiting for an answer (the caller holds the lock)."""

    def _open_link_port(self, hint: str) -> None:
        """Close any previous link, open the port; a port that cannot be opened is
        DeviceNotFound, one line with ``hint`` (what to check)."""
        self._close_link()
        try:
            self._ser = self._open_port(self.port)
        except Exception as exc:
            raise DeviceNotFound(f"{self.title}: cannot open serial port {self.port!r} "
                                 f"({type(exc).__name__}: {exc}); {hint}") from None

    def _wait_for(self, replies: dict, number: int, deadline: float,
                  cv: threading.Condition, poll_s: float) -> Any:
        """The reply to packet ``number`` taken from ``replies`` (filled by the link
        thread), or None at ``deadline`` (``time.monotonic``) or once the link thread is
        gone."""
        with self._lock:
            while number not in replies and time.monotonic() < deadline and \
                    self._link is not None and self._link.is_alive():
                cv.wait(poll_s)
            return replies.pop(number, None)

    def _close_link(self) -> None:
        self._link_stop.set()
        t = self._link
        if t is not None and t is not threading.current_thread():
            t.join(timeout=1.0)
        self._link = None
        self._close_port()

    def _close_port(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception as exc:  # a port already gone (USB glitch) may not close
                self.log.info("%s port close: %s", self.title, exc)

    def disconnect(self) -> None:
        self.stop_now()
        self._close_link()
        with self._lock:
            self._state = StimulatorState.DISCONNECTED
