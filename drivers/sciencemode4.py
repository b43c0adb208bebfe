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

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nmsid.drivers import sciencemode4_protocol as sm4
from nmsid.drivers.errors import DeviceError, DeviceNotFound, StimulatorSettingError
from nmsid.drivers.interfaces import (
    CurrentLimitError,
    StimulatorCapabilities,
    StimulatorState,
)
from nmsid.drivers.leptrino import _serial_module
from nmsid.drivers.pulse_stimulator import SUMMARY_FORMAT, PulseStimulator, steps_down_mA
from nmsid.drivers.sciencemode4_link import STOP_CONFIRM_S, Sm4Link
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
    return steps_down_mA(current_mA, sm4.STEP_MA)


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


class Sm4Stimulator(Sm4Link, PulseStimulator):
    """A P24 or RehaMove3 as a :class:`~nmsid.drivers.interfaces.Stimulator` and a
    :class:`~nmsid.drivers.interfaces.HostStreamedStimulator` (low level; the shared part:
    :class:`~nmsid.drivers.pulse_stimulator.PulseStimulator`).

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

    log = log
    step_mA = sm4.STEP_MA
    stop_confirm_s = STOP_CONFIRM_S

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
        self.model, self.title = model, model.title
        self.interphase_us = int(interphase_us)
        self._open_port = open_port or open_serial
        self._decoder = sm4.Decoder()
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
        self._init_pulses(port, ceiling_ext_mA=ceiling_ext_mA, ceiling_flex_mA=ceiling_flex_mA,
                          extensor_channel=extensor_channel, flexor_channel=flexor_channel,
                          pulse_rate_Hz=pulse_rate_Hz, pulse_width_us=pulse_width_us,
                          clock=clock, sleep=sleep)
        self._cv = threading.Condition(self._lock)
        self.fallback = "in low level every pulse is a command: no further pulse"
        self.operator_action = (f"SWITCH THE {model.title.split()[-1]} OFF, then reconnect "
                                "before the next trial")
        self.repeats_update = False
        """Low level: one command, one pulse (IFU "Low-Level channel configuration"); a
        slot the host skipped has no pulse. Mid level: the device repeats the last update."""

    # -- connection ---------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, start the reader, ask Get_stim_status; a level left initialised by
        a previous program is stopped (confirmed) first."""
        self._open_link_port("check the USB cable and the port name in the Device Manager")
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

    # -- one trial --------------------------------------------------------------------------------
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

    def _write_stop(self) -> None:
        """Ll_stop (Ml_stop), after any pulse being written and before any other."""
        with self._wlock:
            self._write_locked(self._stop_command)

    def _confirm_stop_now(self) -> None:
        self._confirm_stop(self._init[2], resend=False)

    # -- what was delivered -----------------------------------------------------------------------
    def delivery_summary(self) -> dict | None:
        """The last trial's updates as the device acknowledged them (the schema of
        ``docs/stimulators.md``): an update is acknowledged when every pulse command of it
        was (an update of 0 mA on both channels commands nothing); per channel the current
        of each acknowledged update (0: no pulse), ``pulse_index`` its slot."""
        with self._lock:
            sent, got = list(self._sent), dict(self._delivered)
            slots, commanded = list(self._sent_index), dict(self._commanded)
            counts = {**self._counts, "updates_unanswered": len(self._unanswered),
                      "updates_skipped_late": self._skipped_late}
            ended = self._ended_by
        if self._loaded is None and not sent:
            return None
        acked = [i for i in range(len(sent)) if commanded.get(i, set()) <= got.get(i, set())]
        channels = {}
        for name, idx, ch in (("extensor", 0, self.extensor_channel),
                              ("flexor", 1, self.flexor_channel)):
            amps = [sent[i][idx] for i in acked]
            channels[name] = self._channel_summary(name, ch, amps,
                                                   sum(1 for a in amps if a > 0), len(sent))
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
        return {"device": f"{self.model.title} (ScienceMode4, low level)", **self._describe(),
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

    def _check_pulse(self, I_ext_mA: float, I_flex_mA: float) -> None:
        self._points(self.extensor_channel, I_ext_mA)
        self._points(self.flexor_channel, I_flex_mA)

    def _pulse_data(self, channel: int, current_mA: float) -> bytes:
        c = channel - 1                                   # IFU Table 14: channel, connector
        return sm4.ll_channel_config_data(c % 4, c // 4, self._points(channel, current_mA))

    def _reset_device_counts(self) -> None:
        self._delivered: dict[int, set[int]] = {}
        self._commanded: dict[int, set[int]] = {}
        self._counts = {"updates_transfer_error": 0, "updates_answered_late": 0}
        self._unanswered: set[int] = set()
        """Updates with a command unanswered when the next was due, and not since."""
        self._late_acks = {}

    def _send_update(self, k: int, I_ext_mA: float, I_flex_mA: float) -> bool:
        """Write update ``k``, then wait for its answer until the next is due."""
        period = 1.0 / self.pulse_rate_Hz
        with self._wlock:             # never after the stop (stop_now holds it)
            if self._stream_stop.is_set() or self._error:
                return False
            index = len(self._sent)
            self._sent.append((I_ext_mA, I_flex_mA))
            self._sent_index.append(k)
            numbers = self._write_pulses(index, I_ext_mA, I_flex_mA)
        self._await_pulse_acks(numbers, due=max(self._t0 + (k + 1) * period,
                                                self.clock() + period))
        return True

    def _write_pulses(self, index: int, e: float, f: float) -> list[int]:
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

    def _notify(self) -> None:
        self._cv.notify_all()
