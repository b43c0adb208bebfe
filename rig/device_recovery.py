"""Recovery from a device glitch between trials (a USB link lost and back).

Before each trial the engine calls :func:`check_devices_between_trials`, which asks every
device whether its link is alive (:func:`device_problem`: the stimulator's status; the
acquisition's ``device_fault()`` where the driver has one). On a problem:

1. output to zero and an event ``device_glitch``;
2. up to :data:`RECONNECT_ATTEMPTS` reconnects of that device, each logged
   (``reconnect_attempt``): the stimulator by ``disconnect(); connect()``, the acquisition
   by its driver's ``reconnect(fs_Hz)`` (a new port handle / device id / task), which must
   give back the protocol's rate;
3. ``paused`` until the operator confirms (event ``waiting_for_operator``): through the
   engine's ``commands.resume()`` (the GUI's pause/resume path), or, when the engine was given
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

if TYPE_CHECKING:  # annotations only: nmsid.rig.engine imports this module
    from nmsid.drivers.interfaces import RigDevices
    from nmsid.rig.engine import Engine

log = logging.getLogger(__name__)

RECONNECT_ATTEMPTS = 3
"""Reconnects tried per glitch before asking the operator."""
RECONNECT_WAIT_S = 0.5
"""Engine-clock seconds between two reconnect attempts."""

#: ``on_device_glitch(description, reconnected) -> bool``: True = go on (or try again).
GlitchConfirm = Callable[[str, bool], bool]


class DeviceGlitchEnd(Exception):
    """Internal: the operator did not confirm; the engine ends the session cleanly."""


def device_problem(devices: RigDevices) -> tuple[str, str] | None:
    """``(device, what)`` for the first device whose link is down, else None."""
    stim = devices.stimulator
    try:
        st = stim.status()
    except Exception as exc:  # cannot even ask: the link is gone
        return "stimulator", f"status unavailable ({type(exc).__name__}: {exc})"
    if st.state in (StimulatorState.ERROR, StimulatorState.DISCONNECTED) or st.error:
        return "stimulator", st.error or st.state.value
    acq = devices.acquisition
    if isinstance(acq, RecoverableAcquisition):
        try:
            text = acq.device_fault()
        except Exception as exc:
            text = f"device check failed ({type(exc).__name__}: {exc})"
        if text:
            return "acquisition", text
    return None


def check_devices_between_trials(engine: Engine) -> bool:
    """Run before each trial: recover a device whose link is down (see module doc).

    Returns True if there was a glitch (and the session goes on after it).

    Raises
    ------
    DeviceGlitchEnd
        The operator did not confirm: the engine ends the session cleanly.
    """
    problem = device_problem(engine.devices)
    glitch = problem is not None
    while problem is not None:
        device, detail = problem
        engine._stop_output()
        engine._event("device_glitch", f"{device}: {detail}; output off")
        while True:
            ok = _reconnect(engine, device)
            what = (f"{device} glitch ({detail}): "
                    + ("reconnected" if ok else f"NOT reconnected after "
                       f"{RECONNECT_ATTEMPTS} attempts"))
            engine._sm.to(State.PAUSED, what)
            engine._event("waiting_for_operator", what + ("; confirm to resume" if ok
                                                          else "; confirm to try again"))
            if not _operator_confirms(engine, what, ok):
                raise DeviceGlitchEnd(f"{what}; session ended for --resume")
            if ok:
                break
        problem = device_problem(engine.devices)
        if problem is None:
            engine._event("resumed", f"operator confirmed after the {device} reconnect")
            engine._sm.to(State.ARMED, "resumed after reconnect")
    return glitch


def _reconnect(engine: Engine, device: str) -> bool:
    fs_Hz = engine.config.protocol.fs_Hz
    for attempt in range(1, RECONNECT_ATTEMPTS + 1):
        try:
            if device == "stimulator":
                stim = engine.devices.stimulator
                try:
                    stim.disconnect()
                except Exception as exc:  # a dead link may not close cleanly
                    log.info("stimulator.disconnect() before reconnect: %s", exc)
                stim.connect()
            else:
                acq = engine.devices.acquisition
                if not isinstance(acq, RecoverableAcquisition):
                    raise RuntimeError("this acquisition cannot reconnect")
                actual = acq.reconnect(fs_Hz)
                if not math.isclose(actual, fs_Hz, rel_tol=1e-6):
                    raise RuntimeError(f"the acquisition came back at {actual:g} Hz, "
                                       f"not {fs_Hz:g} Hz")
            problem = device_problem(engine.devices)
            if problem is not None and problem[0] == device:
                raise RuntimeError(f"still down: {problem[1]}")
        except Exception as exc:
            engine._event("reconnect_attempt", f"{device}: attempt {attempt} of "
                          f"{RECONNECT_ATTEMPTS} failed ({type(exc).__name__}: {exc})")
            if attempt < RECONNECT_ATTEMPTS:
                engine.clock.sleep(RECONNECT_WAIT_S)
            continue
        engine._event("reconnect_attempt", f"{device}: attempt {attempt} of "
                      f"{RECONNECT_ATTEMPTS} succeeded")
        return True
    return False


def _operator_confirms(engine: Engine, what: str, reconnected: bool) -> bool:
    if engine.on_device_glitch is not None:
        try:
            return bool(engine.on_device_glitch(what, reconnected))
        except (EOFError, KeyboardInterrupt):
            return False
    if engine.trip_policy is TripPolicy.END_SESSION:
        return False   # headless, nobody to confirm: end the session for --resume
    engine._resume_req = False
    engine._wait_operator(lambda: engine._resume_req, "confirm after " + what)
    engine._resume_req = engine._pause_req = False
    return True
