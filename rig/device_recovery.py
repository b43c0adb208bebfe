"""Recovery from a device glitch between trials (a USB link lost and back): a mixin of the
engine.

Before each trial the engine asks every device whether its link is alive
(:meth:`DeviceRecovery._device_problem`: the stimulator's status; the acquisition's
``device_fault()`` where the driver has one). On a problem:

1. output to zero and an event ``device_glitch``;
2. up to :data:`RECONNECT_ATTEMPTS` reconnects of that device, each logged
   (``reconnect_attempt``): the stimulator by ``disconnect(); connect()``, the acquisition
   by its driver's ``reconnect(fs_Hz)`` (a new port handle / device id / task), which must
   give back the protocol's rate;
3. ``paused`` until the operator confirms (event ``waiting_for_operator``): through the
   engine's ``resume()`` (the GUI's pause/resume path), or, when the engine was given
   ``on_device_glitch``, by calling it with the description and whether the reconnect
   worked (``nmsid run``: a prompt on an interactive terminal, ``--resume-after-reconnect``,
   or else "no", which ends the session cleanly so that ``--resume`` continues it);
4. after a "yes": if the reconnect had failed, it is tried again (step 2); otherwise every
   device is checked once more and the session goes on (``resumed``) in the same process.

Nothing recorded is touched: no trial is open between trials. A glitch DURING a trial is
not handled here: the interlock trips and the trial is aborted, as for any fault.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from nmsid.drivers.interfaces import RecoverableAcquisition, StimulatorState
from nmsid.rig.observer import TripPolicy
from nmsid.rig.states import State

if TYPE_CHECKING:
    from nmsid.drivers.interfaces import Clock, RigDevices
    from nmsid.protocols.config import Config
    from nmsid.rig.states import StateMachine

log = logging.getLogger(__name__)

RECONNECT_ATTEMPTS = 3
"""Reconnects tried per glitch before asking the operator."""
RECONNECT_WAIT_S = 0.5
"""Engine-clock seconds between two reconnect attempts."""

#: ``on_device_glitch(description, reconnected) -> bool``: True = go on (or try again).
GlitchConfirm = Callable[[str, bool], bool]


class DeviceGlitchEnd(Exception):
    """Internal: the operator did not confirm; the engine ends the session cleanly."""


class DeviceRecovery:
    """Mixin of :class:`nmsid.rig.engine.Engine` (uses its devices, events, state machine)."""

    on_device_glitch: GlitchConfirm | None = None
    trip_policy: TripPolicy = TripPolicy.WAIT_FOR_REARM

    # The engine's state and steps this mixin uses (set and defined by Engine).
    devices: RigDevices
    config: Config
    clock: Clock
    _sm: StateMachine
    _resume_req: bool
    _pause_req: bool
    _event: Callable[..., None]
    _stop_output: Callable[[], None]
    _wait_operator: Callable[[Callable[[], bool], str], None]

    def _device_problem(self) -> tuple[str, str] | None:
        """``(device, what)`` for the first device whose link is down, else None."""
        stim = self.devices.stimulator
        try:
            st = stim.status()
        except Exception as exc:  # cannot even ask: the link is gone
            return "stimulator", f"status unavailable ({type(exc).__name__}: {exc})"
        if st.state in (StimulatorState.ERROR, StimulatorState.DISCONNECTED) or st.error:
            return "stimulator", st.error or st.state.value
        acq = self.devices.acquisition
        if isinstance(acq, RecoverableAcquisition):
            try:
                text = acq.device_fault()
            except Exception as exc:
                text = f"device check failed ({type(exc).__name__}: {exc})"
            if text:
                return "acquisition", text
        return None

    def _check_devices_between_trials(self) -> bool:
        """Run before each trial: recover a device whose link is down (see module doc).

        Returns True if there was a glitch (and the session goes on after it).
        """
        problem = self._device_problem()
        glitch = problem is not None
        while problem is not None:
            device, detail = problem
            self._stop_output()
            self._event("device_glitch", f"{device}: {detail}; output off")
            while True:
                ok = self._reconnect(device)
                what = (f"{device} glitch ({detail}): "
                        + ("reconnected" if ok else f"NOT reconnected after "
                           f"{RECONNECT_ATTEMPTS} attempts"))
                self._sm.to(State.PAUSED, what)
                self._event("waiting_for_operator", what + ("; confirm to resume" if ok
                                                            else "; confirm to try again"))
                if not self._operator_confirms(what, ok):
                    raise DeviceGlitchEnd(f"{what}; session ended for --resume")
                if ok:
                    break
            problem = self._device_problem()
            if problem is None:
                self._event("resumed", f"operator confirmed after the {device} reconnect")
                self._sm.to(State.ARMED, "resumed after reconnect")
        return glitch

    def _reconnect(self, device: str) -> bool:
        fs_Hz = self.config.protocol.fs_Hz
        for attempt in range(1, RECONNECT_ATTEMPTS + 1):
            try:
                if device == "stimulator":
                    stim = self.devices.stimulator
                    try:
                        stim.disconnect()
                    except Exception as exc:  # a dead link may not close cleanly
                        log.info("stimulator.disconnect() before reconnect: %s", exc)
                    stim.connect()
                else:
                    acq = self.devices.acquisition
                    if not isinstance(acq, RecoverableAcquisition):
                        raise RuntimeError("this acquisition cannot reconnect")
                    actual = acq.reconnect(fs_Hz)
                    if not math.isclose(actual, fs_Hz, rel_tol=1e-6):
                        raise RuntimeError(f"the acquisition came back at {actual:g} Hz, "
                                           f"not {fs_Hz:g} Hz")
                problem = self._device_problem()
                if problem is not None and problem[0] == device:
                    raise RuntimeError(f"still down: {problem[1]}")
            except Exception as exc:
                self._event("reconnect_attempt", f"{device}: attempt {attempt} of "
                            f"{RECONNECT_ATTEMPTS} failed ({type(exc).__name__}: {exc})")
                if attempt < RECONNECT_ATTEMPTS:
                    self.clock.sleep(RECONNECT_WAIT_S)
                continue
            self._event("reconnect_attempt", f"{device}: attempt {attempt} of "
                        f"{RECONNECT_ATTEMPTS} succeeded")
            return True
        return False

    def _operator_confirms(self, what: str, reconnected: bool) -> bool:
        if self.on_device_glitch is not None:
            try:
                return bool(self.on_device_glitch(what, reconnected))
            except (EOFError, KeyboardInterrupt):
                return False
        if self.trip_policy is TripPolicy.END_SESSION:
            return False   # headless, nobody to confirm: end the session for --resume
        self._resume_req = False
        self._wait_operator(lambda: self._resume_req, "confirm after " + what)
        self._resume_req = self._pause_req = False
        return True
