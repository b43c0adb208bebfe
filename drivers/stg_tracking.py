"""How the STG4002 driver follows a running trial from the device's own status.

A mixin of :class:`nmsid.drivers.stg4002.Stg4002Stimulator` (kept apart to keep each module
small): the McsUsbNet poll-status callback, ``QueryTriggerstatus``, and the decision
whether a started trial still runs, ended, or faulted (:func:`nmsid.drivers.stg_status.judge_trial`:
trigger status enum Idle 0 / Running 1 / Finished 2 / Armed 3; ``OvercurrentStatus``
Shutdown = an electrode lost contact, a fault). The attributes it uses (``_dev``, ``_io``,
``_state``, ``_t_start``, ...) and ``_fault`` / ``_release`` belong to the driver.
"""

from __future__ import annotations

import logging

from nmsid.drivers.interfaces import StimulatorState, StimulatorStatus
from nmsid.drivers.stg_status import (DeviceStatus, OvercurrentStatus, TrialProgress,
                                      TriggerStatus, UnknownStatus, decode_status, judge_trial)

log = logging.getLogger("nmsid.drivers.stg4002")


class StgStatusTracking:
    """Status of a started trial, from the device (see the module docstring)."""

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
        state = self._state
        index = -1
        if state is StimulatorState.RUNNING and self._t_start is not None:
            index = int((self._now() - self._t_start) * self._fs_Hz)
        return StimulatorStatus(state=state,
                                output_active=state is StimulatorState.RUNNING
                                or bool(self._stop_error),
                                error=self._stop_error or self._error, sample_index=index)

    def _update_running(self) -> None:
        """Decide from the device's own status whether the trial runs, ended or faulted."""
        now = self._now()
        elapsed = now - self._t_start                      # since just before SendStart
        elapsed_sent = now - (self._t_sent or self._t_start)  # since it returned
        ds = None
        if self._dev is not None:
            try:
                ds = self._query_locked()
            except UnknownStatus as exc:
                self._fault(str(exc))
                return
            except Exception as exc:
                self._fault(f"status query failed: {exc}")
                return
        if ds is None:
            ds = self._poll
        if ds is None:  # nothing reported by this McsUsbNet: the host's clock decides
            if elapsed >= self._duration_s:
                self._state = StimulatorState.STOPPED
            return
        if ds.overcurrent is OvercurrentStatus.SHUTDOWN:
            self._fault(f"overcurrent shutdown after {elapsed:.3f} s: an electrode lost "
                        "contact (Stg5OvercurrentStatus Shutdown); check the electrodes")
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
