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

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from nmsid.drivers import rehastim2_protocol as sm2
from nmsid.drivers.errors import DeviceError, DeviceNotFound, StimulatorSettingError
from nmsid.drivers.interfaces import (
    CurrentLimitError,
    StimulatorCapabilities,
    StimulatorState,
)
from nmsid.drivers.pulse_stimulator import SUMMARY_FORMAT, PulseStimulator, steps_down_mA
from nmsid.drivers.rehastim2_link import STOP_CONFIRM_S, Sm2Link, _open_serial

log = logging.getLogger(__name__)

CONNECT_TIMEOUT_S = 2.5
"""Wait for the device's Init this long. A device still attached to a previous connection
sends Init only after its WatchdogTimeout (1.2 s) and then every InitRepetitionTime
(0.5 s) (SM2 2.3, 5.2): 1.2 + 2 x 0.5 s, with margin."""
STEP_MA = 2
"""The current resolution: RehaStim2 user manual 2.5c, 4.1 "0-130 mA in 65 steps" (the
ScienceMode2 README: 2 mA steps). Currents are rounded DOWN to a step, so an odd value never
reaches a device that might round it up above its ceiling."""
UPDATE_ACK_WAIT_S = 2 * sm2.MAX_RESPONSE_S
"""An update unanswered this long is counted as unanswered and the next one goes out (SM2
2.3: MaxResponseTime 100 ms; x 2 for a host thread scheduled late)."""


def to_steps_mA(current_mA) -> np.ndarray:
    """Currents rounded down to the device's :data:`STEP_MA` (whole steps, ints)."""
    return steps_down_mA(current_mA, STEP_MA).astype(int)


class Rehastim2Stimulator(Sm2Link, PulseStimulator):
    """The RehaStim2 as a :class:`~nmsid.drivers.interfaces.Stimulator` and a
    :class:`~nmsid.drivers.interfaces.HostStreamedStimulator` (the shared part:
    :class:`~nmsid.drivers.pulse_stimulator.PulseStimulator`).

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

    title = "RehaStim2"
    log = log
    _pending_update: tuple[int, float] | None
    step_mA = STEP_MA
    stop_confirm_s = STOP_CONFIRM_S
    interphase_us = sm2.INTERPHASE_US
    fallback = (f"no watchdog feed: the device's watchdog ends the output within "
                f"{sm2.WATCHDOG_TIMEOUT_S:g} s of the last packet, ScienceMode2 2.3, 5.2")
    operator_action = "check the USB link, reconnect before the next trial"

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
        self._decoder = sm2.Decoder()
        self._number = 0
        self._last_sent = 0.0
        self._acks: dict[int, sm2.Packet] = {}
        self._waiting: set[int] = set()
        self._onset_ack_s: float | None = None
        self._t_start_call = 0.0
        self._init_pulses(port, ceiling_ext_mA=ceiling_ext_mA, ceiling_flex_mA=ceiling_flex_mA,
                          extensor_channel=extensor_channel, flexor_channel=flexor_channel,
                          pulse_rate_Hz=pulse_rate_Hz, pulse_width_us=pulse_width_us,
                          clock=clock, sleep=sleep)
        self._ack_cv = threading.Condition(self._lock)
        self.channels = tuple(sorted((extensor_channel, flexor_channel)))
        self._open_port = open_port or _open_serial

    # -- connection ------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, answer the device's Init (SM2 4.1, 3.5), start the link thread."""
        self._open_link_port("check the USB cable, the FTDI driver and that ScienceMode2 "
                             "is selected on the device's start screen (SM2 1.5, 2.1)")
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

    def stimulation_mode(self) -> int:
        """GetStimulationMode (SM2 4.2): 0 start, 1 initialized, 2 started."""
        ack = self._request(sm2.GET_STIM_MODE)
        return ack.data[1] if len(ack.data) > 1 else 0

    # -- one trial ---------------------------------------------------------------------------
    def _steps(self, current_mA) -> np.ndarray:
        return to_steps_mA(current_mA)        # whole 2 mA steps (ints), rounded down

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
        self._onset_ack_s = None
        super().start()

    def _write_stop(self) -> None:
        """StopChannelListMode (SM2 4.3)."""
        self._write(sm2.STOP_CLM)

    def _confirm_stop_now(self) -> None:
        self._confirm_stop()

    # -- what was delivered ---------------------------------------------------------------------
    def delivery_summary(self) -> dict | None:
        """The pulses of the last trial: per channel, the current of every update the device
        acknowledged (``pulse_index``: each one's slot, k / pulse_rate_Hz s after onset), the
        width, the charge per phase, and the updates skipped because the host fell behind
        the time base (plain JSON types)."""
        with self._lock:
            sent, index = list(self._sent), list(self._sent_index)
            got = sorted(set(self._delivered))
            errors, skipped = list(self._ack_errors), self._skipped_late
            onset, ended = self._onset_ack_s, self._ended_by
            busy, transfer, unanswered = self._busy, self._transfer_errors, self._unanswered
        if self._loaded is None and not sent:
            return None
        delivered = [sent[i] for i in got]
        channels = {}
        for name, idx, ch in (("extensor", 0, self.extensor_channel),
                              ("flexor", 1, self.flexor_channel)):
            amps = [p[idx] for p in delivered]
            channels[name] = self._channel_summary(name, ch, amps, len(amps), len(sent))
        return {"format": SUMMARY_FORMAT, "device": "rehastim2",
                "waveshape": self.waveshape().to_json(),
                "carrier_Hz_note": "a pulse device renders no carrier: the session's "
                                   "carrier_Hz is the protocol setting, not delivered",
                "pulse_rate_Hz": self.pulse_rate_Hz, "pulse_width_us": self.pulse_width_us,
                "charge_balanced": "by the device: equal biphasic phases (ScienceMode2 1.2)",
                "repeats_update": True,      # SM2 1.3: in force until the next update
                "updates_planned": len(self._trial), "updates_sent": len(sent),
                "updates_acknowledged": len(got), "update_errors": errors,
                "updates_skipped_late": skipped, "updates_busy": busy,
                "updates_transfer_error": transfer, "updates_unanswered": unanswered,
                "pulse_index": [index[i] for i in got],
                "onset_ack_s": onset, "ended_by": ended or "completed",
                "channels": channels}

    def describe(self) -> dict:
        return {"device": "Hasomed RehaStim2 (ScienceMode2)", **self._describe(),
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

    def _check_pulse(self, I_ext_mA, I_flex_mA) -> None:
        self._pulse_data(int(I_ext_mA), int(I_flex_mA))

    def _before_update(self) -> None:
        self._await_update_ack()             # SM2 5.1 -8: the predecessor answered first

    _after_last_update = _before_update       # the last update's acknowledgement

    def _send_update(self, k: int, I_ext_mA, I_flex_mA) -> bool:
        """One StartChannelListMode (SM2 4.3), registered before its answer can come."""
        data = self._pulse_data(int(I_ext_mA), int(I_flex_mA))
        with self._lock:
            if self._error or self._stream_stop.is_set():
                return False
            number = self._write(sm2.START_CLM, data)
            self._update_numbers[number] = len(self._sent)
            self._pending_update = (number, time.monotonic())
            self._sent.append((I_ext_mA, I_flex_mA))
            self._sent_index.append(k)
        return True

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

    def _reset_device_counts(self) -> None:
        self._ack_errors: list[str] = []
        self._delivered: list[int] = []
        self._update_numbers: dict[int, int] = {}   # packet number -> index in _sent
        self._pending_update = None
        self._busy = self._transfer_errors = self._unanswered = 0

    def _notify(self) -> None:
        self._ack_cv.notify_all()
