"""Hasomed P24 and RehaMove3 over ScienceMode4, low level: one command per biphasic pulse.

Both devices speak the same protocol (:mod:`nmsid.drivers.sciencemode4_protocol`, its
sources and the choice of an own codec); they differ in channels and ranges
(:class:`Sm4Model`: :data:`P24`, :data:`REHAMOVE3`). The driver uses the low-level mode
(IFU "Low-Level commands", RM3 4): ``arm`` sends Ll_init; ``start`` streams one
Ll_channel_config per channel and pulse, host-timed at ``pulse_rate_Hz``, each a
charge-balanced biphasic pulse by construction
(:func:`~nmsid.drivers.sciencemode4_protocol.biphasic_points`: +I, pause, -I, equal
widths); the trial ends with Ll_stop.

The stop is nmsid's E-stop for devices that have none (issue 43; neither device describes an
emergency switch). :meth:`Sm4Stimulator.stop_now` stops the stream, writes Ll_stop at once,
then asks Get_stim_status (IFU Table 7) until the device answers "no level initialised",
resending Ll_stop while it does not (a lost packet, a transfer error: IFU Table 27). If the
device has not confirmed within :data:`~nmsid.drivers.sciencemode4_link.STOP_CONFIRM_S`,
nothing more is written: in low level every pulse is a command, so no command means no
pulse; the operator is told in one line to switch the device off. A pulse command goes out
only after the last one's acknowledgement, which the device sends "after the stimulation
has been executed" (IFU "Ll_channel_config_ack"), or when the next pulse is due if that
acknowledgement was lost; so the device's 10-command buffer (IFU "Low-Level channel
configuration") holds no pulse beyond the stop (at most one more after a late answer): the
last pulse begins at most one pulse period after the stop is asked for.

Safety by construction: each pulse's current is the envelope rounded down to the 0.5 mA step
(IFU Table 15), the envelope was checked against its ceilings
(:class:`~nmsid.drivers.interfaces.CheckedWaveform`), :meth:`Sm4Stimulator._points` refuses
any current above the driver's ceilings, and the codec refuses anything above 130 mA before
encoding.

Time base: no trigger output is described, so ``hardware_trigger`` is False (the engine
starts the acquisition from the host just before ``start``).
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmsid.drivers import sciencemode4_protocol as sm4
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
from nmsid.drivers.leptrino import _serial_module
from nmsid.drivers.sciencemode4_link import Sm4Link
from nmsid.protocols.settings_base import SettingProblem

log = logging.getLogger(__name__)

PULSE_ACK_WAIT_S = 0.2
"""A pulse unacknowledged when the next is due (or after this long) is counted as
unanswered and the next goes out: the device answers after the pulse, within a few ms. Only
then can a command be outstanding with the next (a late answer): at most two."""
MAX_HOST_RATE_HZ = 100.0
"""Low level is host-timed, one command per channel and pulse from a Python thread: nmsid
streams at most 100 pulses per second per channel (the devices allow more: P24 0.5 ms
period, IFU Technical Specification; RehaMove3 500 Hz, RM3 1.2)."""
SUMMARY_FORMAT = "nmsid-stimulation-1"


@dataclass(frozen=True)
class Sm4Model:
    """What differs between the ScienceMode4 devices nmsid drives."""

    title: str
    n_channels: int
    """P24: 4 channels x 2 connectors (IFU Table 14); RehaMove3: 4 (RM3 1.5)."""
    min_width_us: int
    max_width_us: int
    """Per phase; a phase is one low-level point, at most 4095 us (IFU Table 15)."""
    source: str


P24 = Sm4Model("Hasomed P24", 8, 10, sm4.MAX_POINT_US,
               "IFU Technical Specification: pulse width 10 - 65520 us; Table 15: a point "
               "<= 4095 us")
REHAMOVE3 = Sm4Model("Hasomed RehaMove3", 4, 20, sm4.MAX_POINT_US,
                     "RM3 1.2: pulse width 20 - 16000 us; 4.2: a point <= 4095 us")


def to_steps_mA(current_mA) -> np.ndarray:
    """Currents rounded DOWN to the 0.5 mA step (IFU Table 15), never up past a ceiling."""
    c = np.asarray(current_mA, dtype=float)
    return sm4.STEP_MA * np.floor(c / sm4.STEP_MA + 1e-9)


def settings_issue(model: Sm4Model, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                   extensor_channel: int, flexor_channel: int, pulse_rate_Hz: float,
                   pulse_width_us: int, interphase_us: int) -> tuple[str, object, str] | None:
    """``(key, value, what is valid)`` of the first setting outside the device's documented
    ranges, or None."""
    for key, ch in (("extensor_channel", extensor_channel), ("flexor_channel", flexor_channel)):
        if not 1 <= ch <= model.n_channels:
            return key, ch, f"valid 1 .. {model.n_channels}"
    if extensor_channel == flexor_channel:
        return "flexor_channel", flexor_channel, "must differ from extensor_channel"
    for key, c in (("ceiling_ext_mA", ceiling_ext_mA), ("ceiling_flex_mA", ceiling_flex_mA)):
        if not (math.isfinite(c) and 0 < c <= sm4.MAX_CURRENT_MA):
            return key, c, "valid > 0 and <= 130 mA (IFU Technical Specification, RM3 1.2)"
    if not 1.0 <= pulse_rate_Hz <= MAX_HOST_RATE_HZ:
        return ("pulse_rate_Hz", pulse_rate_Hz,
                f"valid 1 .. {MAX_HOST_RATE_HZ:g} Hz (host-timed low level)")
    if not model.min_width_us <= pulse_width_us <= model.max_width_us:
        return ("pulse_width_us", pulse_width_us,
                f"valid {model.min_width_us} .. {model.max_width_us} us ({model.source})")
    if not 0 <= interphase_us <= sm4.MAX_POINT_US:
        return "interphase_us", interphase_us, "valid 0 .. 4095 us (IFU Table 15)"
    if (2 * pulse_width_us + interphase_us) * 1e-6 * 2 >= 1.0 / pulse_rate_Hz:
        return ("pulse_width_us", pulse_width_us,
                f"two pulses of 2 x width + {interphase_us} us must fit in one period at "
                f"{pulse_rate_Hz:g} Hz")
    return None


def check_settings(model: Sm4Model, **settings) -> None:
    """Refuse settings outside the device's documented ranges (one line)."""
    issue = settings_issue(model, **settings)
    if issue is not None:
        key, value, valid = issue
        raise StimulatorSettingError(f"{model.title}: {key} = {value!r}: {valid}")


def settings_problem(model: Sm4Model, cfg) -> SettingProblem | None:
    """The settings models' cross-key rules (``drivers/<kind>_settings.py``)."""
    if not cfg.port:
        return SettingProblem("port", "", f"the {model.title}'s serial port (COM5, "
                              "/dev/ttyACM0; the Device Manager)")
    issue = settings_issue(model, ceiling_ext_mA=cfg.ceiling_ext_mA,
                           ceiling_flex_mA=cfg.ceiling_flex_mA,
                           extensor_channel=cfg.extensor_channel,
                           flexor_channel=cfg.flexor_channel, pulse_rate_Hz=cfg.pulse_rate_Hz,
                           pulse_width_us=cfg.pulse_width_us, interphase_us=cfg.interphase_us)
    if issue is not None:
        return SettingProblem(*issue)
    period2 = 2000.0 / cfg.pulse_rate_Hz
    if cfg.mode == "mid" and abs(period2 - round(period2)) > 1e-9:
        return SettingProblem("pulse_rate_Hz", cfg.pulse_rate_Hz, "with mode = \"mid\" the "
                              "period 1000 / rate ms must be on the 0.5 ms grid (IFU Table "
                              "22): e.g. 50, 40, 25, 20 Hz")
    return None


def open_serial(port: str):
    """pyserial at IFU Table 1 / RM3 Table 1: 3 000 000 baud, 8N2, RTS/CTS."""
    serial = _serial_module()
    return serial.Serial(port, baudrate=sm4.BAUDRATE, bytesize=8, parity="N", stopbits=2,
                         rtscts=True, timeout=0.02, write_timeout=0.5)


class Sm4Stimulator(Sm4Link):
    """A P24 or RehaMove3 as a :class:`~nmsid.drivers.interfaces.Stimulator` and a
    :class:`~nmsid.drivers.interfaces.HostStreamedStimulator` (low level).

    Parameters
    ----------
    port : str
        The device's virtual serial port (``COM5``, ``/dev/ttyACM0``).
    model : Sm4Model
        :data:`P24` or :data:`REHAMOVE3`.
    ceiling_ext_mA, ceiling_flex_mA : float
        The session's ceilings; no pulse above them is ever written.
    extensor_channel, flexor_channel : int
        1-based; on the P24 channels 5 .. 8 are connector 2 (IFU Table 14).
    pulse_rate_Hz, pulse_width_us, interphase_us : float, int, int
        Pulses per second per channel, width of each phase, pause between the phases.
    open_port, clock, sleep : callables, optional
        The port opener (the fake in fake mode), the time source and wait (the bench's).
    """

    def __init__(self, port: str, model: Sm4Model, *, ceiling_ext_mA: float,
                 ceiling_flex_mA: float, extensor_channel: int = 1, flexor_channel: int = 2,
                 pulse_rate_Hz: float = 40.0, pulse_width_us: int = 300,
                 interphase_us: int = 100, open_port: Callable | None = None,
                 clock: Callable[[], float] | None = None,
                 sleep: Callable[[float], None] | None = None):
        check_settings(model, ceiling_ext_mA=ceiling_ext_mA, ceiling_flex_mA=ceiling_flex_mA,
                       extensor_channel=extensor_channel, flexor_channel=flexor_channel,
                       pulse_rate_Hz=pulse_rate_Hz, pulse_width_us=pulse_width_us,
                       interphase_us=interphase_us)
        self.port, self.model = port, model
        self.extensor_channel, self.flexor_channel = extensor_channel, flexor_channel
        self.ceilings = {extensor_channel: float(ceiling_ext_mA),
                         flexor_channel: float(ceiling_flex_mA)}
        self._stream_ceilings = dict(self.ceilings)
        self.pulse_rate_Hz = float(pulse_rate_Hz)
        self.pulse_width_us, self.interphase_us = int(pulse_width_us), int(interphase_us)
        self._open_port = open_port or open_serial
        self.clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self._ser: Any = None
        self._decoder = sm4.Decoder()
        self._wlock = threading.Lock()
        self._lock = threading.RLock()
        self._cv = threading.Condition(self._lock)
        self._number = 0
        self._replies: dict[int, sm4.Packet | sm4.BadPacket] = {}
        self._pulse_acks: dict[int, tuple[int, tuple[int, ...]]] = {}
        """Packet number -> (update index, channels) of each pulse command unanswered."""
        self._late_acks: dict[int, tuple[int, tuple[int, ...]]] = {}
        """The same, of commands still unanswered when the next pulse was due: an answer
        that comes later counts them answered (``updates_answered_late``)."""
        self._init = (sm4.LL_INIT, sm4.ll_init_data(), sm4.STIM_LL)
        """The level's init command, its data and the level it enters (IFU Table 7)."""
        self._stop_command, self._update_ack = sm4.LL_STOP, sm4.LL_CHANNEL_CONFIG_ACK
        self._silent = False
        self._error = ""
        self._state = StimulatorState.DISCONNECTED
        self._link: threading.Thread | None = None
        self._link_stop = threading.Event()
        self._stream: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._queue: collections.deque[tuple[float, float]] = collections.deque()
        self._streaming_open = False
        self._trial: list[tuple[float, float]] = []
        self._loaded: CheckedWaveform | None = None
        self._ended_by = ""
        self._reset_counts()
        self.fallback = "in low level every pulse is a command: no further pulse"
        self.repeats_update = False
        """Low level: one command, one pulse (IFU "Low-Level channel configuration"); a
        slot the host skipped has no pulse. Mid level: the device repeats the last update."""
        self.stop_log: list[tuple[float, str]] = []
        """(clock time, what) of each stop: asked, confirmed or unconfirmed (tests, bench)."""

    # -- connection ---------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, start the reader, ask Get_stim_status; a level left initialised by
        a previous program is stopped (confirmed) first."""
        self._close_link()
        try:
            self._ser = self._open_port(self.port)
        except Exception as exc:
            raise DeviceNotFound(f"{self.model.title}: cannot open serial port {self.port!r} "
                                 f"({type(exc).__name__}: {exc}); check the USB cable and "
                                 "the port name in the Device Manager") from None
        self._decoder, self._silent = sm4.Decoder(), False
        with self._lock:
            self._error, self._replies = "", {}
            self._state = StimulatorState.IDLE
        self._link_stop.clear()
        self._link = threading.Thread(target=self._link_loop, name="sm4-link", daemon=True)
        self._link.start()
        try:
            level = self.stim_level()
        except DeviceError as exc:
            self._close_link()
            raise DeviceNotFound(f"{self.model.title} on {self.port}: {exc}") from None
        if level != sm4.STIM_NONE and not self._confirm_stop(level):
            raise DeviceError(self._error)

    def stim_level(self) -> int:
        """Get_stim_status (IFU Table 7): 0 none, 1 low level, 2 mid level, 3 running."""
        ack = self._request(sm4.GET_STIM_STATUS)
        return ack.data[1] if len(ack.data) > 1 else 0

    def capabilities(self) -> StimulatorCapabilities:
        return StimulatorCapabilities(
            n_channels=self.model.n_channels, max_current_mA=sm4.MAX_CURRENT_MA,
            resolution_mA=sm4.STEP_MA, output_rate_Hz=self.pulse_rate_Hz,
            model=self.model.title, waveshape=self.waveshape(), hardware_trigger=False)

    def waveshape(self) -> Waveshape:
        return Waveshape(kind=BIPHASIC_PULSES, pulse_rate_Hz=self.pulse_rate_Hz,
                         pulse_width_us=float(self.pulse_width_us),
                         interphase_us=float(self.interphase_us), modulation="amplitude")

    def disconnect(self) -> None:
        self.stop_now()
        self._close_link()
        with self._lock:
            self._state = StimulatorState.DISCONNECTED

    # -- one trial --------------------------------------------------------------------------------
    def load(self, waveform: CheckedWaveform) -> None:
        """Each pulse's current: the envelope at the pulse, rounded down to 0.5 mA."""
        self._check_usable("load")
        for ch, ceiling in ((self.extensor_channel, waveform.ceiling_ext_mA),
                            (self.flexor_channel, waveform.ceiling_flex_mA)):
            if ceiling > self.ceilings[ch] + 1e-9:
                raise CurrentLimitError(f"waveform ceiling {ceiling:g} mA on {self.model.title}"
                                        f" channel {ch} is above the driver's "
                                        f"{self.ceilings[ch]:g} mA; nothing was sent")
        n = math.floor(waveform.duration_s * self.pulse_rate_Hz + 1e-9)
        k = np.minimum((np.arange(n) / self.pulse_rate_Hz * waveform.fs_Hz + 1e-9)
                       .astype(np.int64), waveform.n_samples - 1)
        pulses = list(zip(to_steps_mA(np.asarray(waveform.I_ext_mA)[k]).tolist(),
                          to_steps_mA(np.asarray(waveform.I_flex_mA)[k]).tolist(), strict=True))
        for e, f in pulses:                   # by construction; checked once more
            self._points(self.extensor_channel, e)
            self._points(self.flexor_channel, f)
        with self._lock:
            self._trial, self._loaded = pulses, waveform
            self._state = StimulatorState.LOADED

    def arm(self) -> None:
        """Ll_init (IFU Table 12: standard 150 V, no measurement); a stream is armed already."""
        self._check_usable("arm")
        with self._lock:
            if self._streaming_open and self._state is StimulatorState.ARMED:
                return
        level = self.stim_level()
        if level != sm4.STIM_NONE and not self._confirm_stop(level):
            raise DeviceError(self._error)
        command, data, level = self._init
        ack = self._request(command, data)
        if ack.result == sm4.NOT_INITIALIZED and self.stim_level() == level:
            pass     # a resent init after a late answer: the first one initialised it
        elif ack.result != sm4.OK:
            raise DeviceError(f"{self.model.title} refused its init (command {command}): "
                              f"{sm4.RESULT_TEXT.get(ack.result, ack.result)} (IFU Table 27)")
        with self._lock:
            self._state = StimulatorState.ARMED

    def start(self) -> None:
        with self._lock:
            if self._state is not StimulatorState.ARMED:
                raise DeviceError(f"{self.model.title}: start() in state "
                                  f"{self._state.value}; load() and arm() first")
            if not self._streaming_open:
                self._queue = collections.deque(self._trial)
            self._reset_counts()          # a stream runs until close_stream (or a stop)
            self._state = StimulatorState.RUNNING
        self._stream_stop.clear()
        self._stream = threading.Thread(target=self._stream_loop, name="sm4-stream",
                                        daemon=True)
        self._stream.start()

    def stop_now(self) -> None:
        """Ll_stop now, confirmed by the device (module docstring). Thread-safe, idempotent,
        never raises."""
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
            with self._wlock:                 # after any pulse being written: none follows
                self._write_locked(self._stop_command)
        except Exception as exc:
            self._unconfirmed(f"the stop could not be sent ({type(exc).__name__}: {exc})")
            return
        t = self._stream
        if t is not None and t is not threading.current_thread():
            t.join(timeout=1.0)
        self._confirm_stop(self._init[2], resend=False)

    def status(self) -> StimulatorStatus:
        with self._lock:
            st = self._state
            running = st is StimulatorState.RUNNING
            return StimulatorStatus(state=st, output_active=running, error=self._error,
                                    sample_index=len(self._sent) if running else -1)

    # -- host-streamed capability -------------------------------------------------------------
    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float,
                    update_Hz: float) -> float:
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
            self._reset_counts()
            self._streaming_open = True
        return self.pulse_rate_Hz

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        lim = self._stream_ceilings
        for name, arr, ch in (("I_ext_mA", I_ext_mA, self.extensor_channel),
                              ("I_flex_mA", I_flex_mA, self.flexor_channel)):
            a = np.asarray(arr, float)
            if a.size and (not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > lim[ch]):
                raise CurrentLimitError(f"{name} outside 0 .. {lim[ch]:g} mA (or not "
                                        "finite); nothing was sent")
        ext, flex = to_steps_mA(I_ext_mA), to_steps_mA(I_flex_mA)
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

    # -- what was delivered -----------------------------------------------------------------------
    def delivery_summary(self) -> dict | None:
        """The last trial's updates as the device acknowledged them (the schema of
        ``docs/stimulators.md``): an update is acknowledged when every pulse command of it
        was (an update of 0 mA on both channels commands nothing); per channel the current
        of each acknowledged update (0: no pulse), ``pulse_index`` its slot."""
        with self._lock:
            sent, got = list(self._sent), dict(self._delivered)
            slots, commanded = list(self._sent_index), dict(self._commanded)
            counts = {**self._counts, "updates_unanswered": len(self._unanswered)}
            ended = self._ended_by
        if self._loaded is None and not sent:
            return None
        acked = [i for i in range(len(sent)) if commanded.get(i, set()) <= got.get(i, set())]
        channels = {}
        for name, idx, ch in (("extensor", 0, self.extensor_channel),
                              ("flexor", 1, self.flexor_channel)):
            amps = [sent[i][idx] for i in acked]
            peak = max(amps, default=0.0)
            channels[name] = {"name": name, "channel": ch, "pulses_acknowledged":
                              sum(1 for a in amps if a > 0), "pulses_sent": len(sent),
                              "pulse_current_mA": amps, "peak_current_mA": float(peak),
                              "max_charge_per_phase_nC": float(peak * self.pulse_width_us),
                              "net_charge_per_trial_uC": 0.0,
                              "ceiling_mA": self.ceilings[ch]}
        return {"format": SUMMARY_FORMAT, "device": self.model.title,
                "mode": type(self).__name__, "waveshape": self.waveshape().to_json(),
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us,
                "interphase_us": self.interphase_us,
                "charge_balanced": "by construction: +I, pause, -I of equal width per pulse",
                "repeats_update": self.repeats_update,
                "updates_planned": len(self._trial), "updates_sent": len(sent),
                "updates_acknowledged": len(acked), "updates_busy": 0, **counts,
                "pulse_index": [slots[i] for i in acked],
                "ended_by": ended or "completed", "channels": channels}

    def describe(self) -> dict:
        return {"device": f"{self.model.title} (ScienceMode4, low level)", "port": self.port,
                "extensor_channel": self.extensor_channel,
                "flexor_channel": self.flexor_channel,
                "ceiling_ext_mA": self.ceilings[self.extensor_channel],
                "ceiling_flex_mA": self.ceilings[self.flexor_channel],
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us,
                "interphase_us": self.interphase_us,
                "trigger_output": "none described: acquisition host-started",
                "emergency_stop": "none on the device: nmsid's stop (confirmed Ll_stop)",
                "state": self.status().state.value, "error": self._error}

    # -- internals ---------------------------------------------------------------------------------
    def _points(self, channel: int, current_mA: float) -> list[tuple[int, float]]:
        lim = self.ceilings[channel]
        if not 0 <= current_mA <= lim + 1e-9:
            raise CurrentLimitError(f"{self.model.title} channel {channel}: {current_mA} mA "
                                    f"outside 0 .. {lim:g} mA; nothing was sent")
        return sm4.biphasic_points(current_mA, self.pulse_width_us, self.interphase_us)

    def _pulse_data(self, channel: int, current_mA: float) -> bytes:
        c = channel - 1                                   # IFU Table 14: channel, connector
        return sm4.ll_channel_config_data(c % 4, c // 4, self._points(channel, current_mA))

    def _reset_counts(self) -> None:
        self._sent: list[tuple[float, float]] = []
        self._sent_index: list[int] = []       # each update's slot k (k / rate after onset)
        self._delivered: dict[int, set[int]] = {}
        self._commanded: dict[int, set[int]] = {}
        self._counts = {"updates_transfer_error": 0, "updates_skipped_late": 0,
                        "updates_answered_late": 0}
        self._unanswered: set[int] = set()
        """Updates with a command unanswered when the next was due, and not since."""
        self._late_acks = {}
        self._ended_by = ""

    def _stream_loop(self) -> None:
        period = 1.0 / self.pulse_rate_Hz
        t0, k = self.clock(), 0
        try:
            while not self._stream_stop.is_set():
                with self._lock:
                    if self._queue:
                        e, f = self._queue.popleft()
                    elif self._streaming_open:
                        e = f = -1.0
                    else:
                        break
                if e < 0:
                    self._sleep(period / 4)
                    self._after_update()
                    continue
                wait = t0 + k * period - self.clock()
                if wait > 0:
                    self._sleep(wait)
                elif not self._streaming_open and -wait > period:   # behind: keep time axis
                    late = min(int(-wait / period), len(self._queue))
                    with self._lock:
                        for _ in range(late):
                            e, f = self._queue.popleft()
                        self._counts["updates_skipped_late"] += late
                    k += late
                with self._wlock:             # never after the stop (stop_now holds it)
                    if self._stream_stop.is_set() or self._error:
                        break
                    index = len(self._sent)
                    self._sent.append((e, f))
                    self._sent_index.append(k)
                    numbers = self._send_update(index, e, f)
                self._await_pulse_acks(numbers, due=max(t0 + (k + 1) * period,
                                                        self.clock() + period))
                self._after_update()
                k += 1
        except Exception as exc:
            with self._lock:
                self._error = self._error or (f"{self.model.title} link lost while "
                                              f"stimulating ({type(exc).__name__}: {exc})")
                self._state = StimulatorState.ERROR
            return
        if not self._stream_stop.is_set():
            with self._lock:
                self._ended_by = self._ended_by or "completed"
            self.stop_now()

    def _send_update(self, index: int, e: float, f: float) -> list[int]:
        """One Ll_channel_config per channel with current (the caller holds ``_wlock``)."""
        numbers = []
        for ch, cur in ((self.extensor_channel, e), (self.flexor_channel, f)):
            if cur > 0:
                data = self._pulse_data(ch, cur)
                with self._lock:              # registered before its ack can be handled
                    n = self._write_locked(sm4.LL_CHANNEL_CONFIG, data)
                    self._pulse_acks[n] = (index, (ch,))
                    self._commanded.setdefault(index, set()).add(ch)
                numbers.append(n)
        return numbers

    def _after_update(self) -> None:
        """Between updates (the mid level's keep-alive and error poll); nothing in low level."""

    def _await_pulse_acks(self, numbers: list[int], due: float) -> None:
        """The next pulse goes out after these were acknowledged (at most one pulse command
        outstanding per channel: module docstring), or when it is due (``due``, the driver's
        clock: a lost packet costs its own slot only), at most :data:`PULSE_ACK_WAIT_S`."""
        deadline = time.monotonic() + PULSE_ACK_WAIT_S
        with self._lock:
            while any(n in self._pulse_acks for n in numbers) and not self._error \
                    and not self._stream_stop.is_set():
                if time.monotonic() > deadline or self.clock() >= due:
                    for n in numbers:
                        entry = self._pulse_acks.pop(n, None)
                        if entry is not None:     # lost, or answered late (a busy host)
                            self._late_acks[n] = entry
                            self._unanswered.add(entry[0])
                    return
                self._cv.wait(0.002)

    def _check_usable(self, what: str) -> None:
        with self._lock:
            if self._state is StimulatorState.DISCONNECTED:
                raise DeviceError(f"{self.model.title}: {what}() before connect()")
            if self._error:
                raise DeviceError(self._error)
