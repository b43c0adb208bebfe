"""How the STG4002 driver follows a running trial from the device's own status.

A mixin of :class:`nmsid.drivers.stg4002.Stg4002Stimulator` (kept apart to keep each module
small): the McsUsbNet poll-status callback, ``QueryTriggerstatus``, and the decision
whether a started trial still runs, ended, or faulted (:func:`nmsid.drivers.stg_status.judge_trial`:
trigger status enum Idle 0 / Running 1 / Finished 2 / Armed 3; ``OvercurrentStatus``
Shutdown a fault; an STG4002 does not report electrode-off, see ``docs/hardware.md``). The
attributes it uses (``_dev``, ``_io``, ``_state``, ``_t_start``, ...) and ``_fault`` / ``_release``
belong to the driver.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from nmsid.drivers.interfaces import StimulatorState, StimulatorStatus
from nmsid.drivers.stg_status import (
    DeviceStatus,
    OvercurrentStatus,
    TrialProgress,
    TriggerStatus,
    UnknownStatus,
    decode_status,
    judge_trial,
)

log = logging.getLogger("nmsid.drivers.stg4002")

_BETWEEN_TRIALS = (StimulatorState.IDLE, StimulatorState.LOADED, StimulatorState.ARMED,
                   StimulatorState.STOPPED)


class StgStatusTracking:
    """Status of a started trial, from the device (see the module docstring)."""

    # The driver's state this mixin reads and writes (set by Stg4002Stimulator).
    _dev: Any
    """The McsUsbNet CStg200xDownloadNet (a .NET object, untyped), None when disconnected."""
    _io: threading.Lock
    _state: StimulatorState
    _t_start: float | None
    _t_sent: float | None
    _fs_Hz: float
    _duration_s: float
    _error: str
    _stop_error: str
    _seen_running: bool
    _foreign_start: bool
    _poll: DeviceStatus | None
    _now: Callable[[], float]
    _fault: Callable[[str], None]
    _release: Callable[[], None]

    def _on_poll(self, status, stg_status, index_list) -> None:
        """McsUsbNet poll-status callback (runs on the library's thread)."""
        try:
            ds = decode_status(stg_status)
        except UnknownStatus as exc:
            log.error("STG poll status: %s", exc)
            self._error = self._error or str(exc)
            return
        self._poll = ds
        if ds.trigger(0) in (TriggerStatus.RUNNING, TriggerStatus.FINISHED):
            self._seen_running = True  # a short Running may fall between two queries
        # Running reported while no trial of ours can be under way (a trial is loaded or
        # nothing is): started by the front panel or Trigger In; stopped at the next
        # status() (not on the library's thread). ARMED / RUNNING / STOPPED are left to the
        # query in _check_between_trials (a start or a stop may be in flight).
        if self._state in (StimulatorState.IDLE, StimulatorState.LOADED) and any(
                t is TriggerStatus.RUNNING for t in ds.triggers):
            self._foreign_start = True

    def _query_locked(self) -> DeviceStatus | None:
        """``QueryTriggerstatus()`` decoded, or None if this McsUsbNet lacks it."""
        query = getattr(self._dev, "QueryTriggerstatus", None)
        if query is None:
            return None
        return decode_status(query())

    def status(self) -> StimulatorStatus:
        if self._state is StimulatorState.RUNNING and self._t_start is not None:
            if self._io.acquire(blocking=False):
                try:
                    self._update_running()
                finally:
                    self._release()
        elif self._state in _BETWEEN_TRIALS and self._dev is not None:
            if self._io.acquire(blocking=False):
                try:
                    self._check_between_trials()
                finally:
                    self._release()
        state = self._state
        index = -1
        if state is StimulatorState.RUNNING and self._t_start is not None:
            index = int((self._now() - self._t_start) * self._fs_Hz)
        return StimulatorStatus(state=state,
                                output_active=state is StimulatorState.RUNNING
                                or bool(self._stop_error),
                                error=self._stop_error or self._error, sample_index=index)

    def _check_between_trials(self) -> None:
        """Poll the device between trials: a pattern started by the front-panel Start button
        or a pulse on Trigger In (the STG4000 manual: the STG plays its memory without a PC)
        is stopped at once and becomes a fault the operator sees."""
        foreign = self._foreign_start
        self._foreign_start = False
        try:
            ds = self._query_locked()
        except Exception as exc:  # the link is down: the engine's device check reports it
            self._state = StimulatorState.ERROR
            self._error = f"status query between trials failed: {exc}"
            log.error("STG: %s", self._error)
            return
        running = [i + 1 for i, t in enumerate(ds.triggers) if t is TriggerStatus.RUNNING] \
            if ds is not None else []
        if running or foreign:
            which = ", ".join(str(i) for i in running) or "?"
            self._fault(f"the STG started output on trigger {which} between trials, not "
                        "started by nmsid (front-panel Start button or a pulse on Trigger In?);"
                        " output stopped; check the Trigger In wiring and keep the front "
                        "panel untouched")

    def _update_running(self) -> None:
        """Decide from the device's own status whether the trial runs, ended or faulted."""
        t_start = self._t_start
        if t_start is None:  # no trial started (status() asks only while one runs)
            return
        before = self._now()
        elapsed_sent = before - (self._t_sent or t_start)  # since SendStart returned, up to
        ds = None                                           # the query: it can only be later
        if self._dev is not None:
            try:
                ds = self._query_locked()
            except UnknownStatus as exc:
                self._fault(str(exc))
                return
            except Exception as exc:
                self._fault(f"status query failed: {exc}")
                return
        # since just before SendStart, up to the reply: the device answered no later than
        # this, so an end it reports is early only against this bound (read before the
        # query, a host stall between the clock and the query made an end on time look
        # early: seen at load 4-8 on the 10x fake bench)
        elapsed = self._now() - t_start
        if ds is None:
            ds = self._poll
        if ds is None:  # nothing reported by this McsUsbNet: the host's clock decides
            if elapsed >= self._duration_s:
                self._state = StimulatorState.STOPPED
            return
        if ds.overcurrent is OvercurrentStatus.SHUTDOWN:
            # StgStatusNet's field is typed Stg5OvercurrentStatusEnumNet (an STG5 family
            # status); an STG4002 does not report electrode-off through it: an open output
            # drives the voltage to its maximum (STG4000 manual 12.5). A Shutdown reported
            # here is still a fault, but not proof of lost contact.
            self._fault(f"the STG reported an overcurrent shutdown after {elapsed:.3f} s "
                        "(OvercurrentStatus Shutdown); check the electrodes and leads")
            return
        trig = ds.trigger(0)
        if trig is TriggerStatus.RUNNING:
            self._seen_running = True
        verdict = judge_trial(trig, self._seen_running, elapsed, self._duration_s,
                              elapsed_sent_s=elapsed_sent)
        if verdict is TrialProgress.RUNNING:
            return
        if verdict in (TrialProgress.ENDED, TrialProgress.ENDED_UNSEEN):
            if verdict is TrialProgress.ENDED_UNSEEN:
                log.warning("STG never reported Running; trial taken as ended after "
                            "%.3f s", elapsed)
            self._state = StimulatorState.STOPPED
        elif verdict is TrialProgress.EARLY_END:
            self._fault(f"the STG ended the pattern after {elapsed:.3f} s of "
                        f"{self._duration_s:.3f} s (trigger status {trig.name}; a second "
                        "pulse on its trigger input stops it)")
        else:
            self._fault(f"the STG still reports {trig.name} {elapsed:.3f} s after a "
                        f"{self._duration_s:.3f} s trial started")
