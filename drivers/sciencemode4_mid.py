"""Hasomed P24 and RehaMove3 in ScienceMode4's mid level: the device times the pulses.

Mid level (IFU "Mid-Level commands", RM3 5): ``arm`` sends Ml_init with "stop on all
errors" (IFU Table 20); each update of the trial (or stream) is one Ml_update of both
channels (IFU Table 22: the period of ``1000 / pulse_rate_Hz`` ms on its 0.5 ms grid, the
biphasic points of the current, ramp 0), which the device repeats until the next; a channel
at 0 mA gets pulses of 0 mA. The device stops by itself 2 s after the last Ml_update or
Ml_get_current_data (IFU "Mid-Level Update", RM3 5.1): while a stream waits for updates the
driver sends Ml_get_current_data every :data:`KEEPALIVE_S`, and reads in its answer the
electrode errors (IFU Table 26, RM3 5.3), which end the trial in ERROR.

The stop is Ml_stop, confirmed by Get_stim_status as in low level; unconfirmed, nothing more
is written, the keep-alive included, so the device's own 2 s timeout ends the output, and
the operator is told to switch it off.
"""

from __future__ import annotations

import time

from nmsid.drivers import sciencemode4_protocol as sm4
from nmsid.drivers.errors import StimulatorSettingError
from nmsid.drivers.interfaces import StimulatorState
from nmsid.drivers.sciencemode4 import Sm4Stimulator

KEEPALIVE_S = 0.5
"""Ml_get_current_data at least this often (a quarter of the device's 2 s timeout)."""


class Sm4MidLevelStimulator(Sm4Stimulator):
    """:class:`~nmsid.drivers.sciencemode4.Sm4Stimulator` in the mid level (module
    docstring); the same parameters."""

    _error: str

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.period_ms = 1000.0 / self.pulse_rate_Hz
        if abs(self.period_ms * 2 - round(self.period_ms * 2)) > 1e-9:
            raise StimulatorSettingError(
                f"{self.model.title}: pulse_rate_Hz = {self.pulse_rate_Hz:g} gives a period "
                f"of {self.period_ms:g} ms; the mid level sets periods in 0.5 ms steps (IFU "
                "Table 22): e.g. 50, 40, 25, 20 Hz")
        self._init = (sm4.ML_INIT, bytes((1,)), sm4.STIM_ML)
        self._stop_command, self._update_ack = sm4.ML_STOP, sm4.ML_UPDATE_ACK
        self.fallback = ("no keep-alive: the device stops within 2 s of the last one, IFU "
                         "'Mid-Level Update'")
        self._last_poll = 0.0
        self.repeats_update = True       # IFU "Mid-Level Update": repeated until the next

    def _write_pulses(self, index: int, e: float, f: float) -> list[int]:
        """One Ml_update of both channels (the caller holds ``_wlock``)."""
        channels = {}
        for ch, cur in ((self.extensor_channel, e), (self.flexor_channel, f)):
            channels[ch - 1] = (self.period_ms, self._points(ch, cur))
        data = sm4.ml_update_data(channels)
        with self._lock:                      # registered before its ack can be handled
            n = self._write_locked(sm4.ML_UPDATE, data)
            self._pulse_acks[n] = (index, (self.extensor_channel, self.flexor_channel))
            self._commanded[index] = {self.extensor_channel, self.flexor_channel}
        return [n]

    def _idle(self) -> None:
        """The keep-alive and the electrode check, every :data:`KEEPALIVE_S`."""
        now = time.monotonic()
        if now - self._last_poll < KEEPALIVE_S or self._stream_stop.is_set():
            return
        self._last_poll = now
        reply = self._ask(sm4.ML_GET_CURRENT_DATA, sm4.ml_get_current_data_data())
        if isinstance(reply, sm4.Packet) and len(reply.data) >= 3:
            bad = [c for c in (self.extensor_channel, self.flexor_channel)
                   if c <= 4 and reply.data[2] & (1 << (c - 1))]
            if bad:
                with self._lock:
                    self._error = self._error or (f"{self.model.title}: electrode error on "
                                                  f"channel(s) {bad} (IFU Table 26); "
                                                  "stimulation stopped")
                    self._state = StimulatorState.ERROR
