"""A simulated two-channel current stimulator (STG4002-like) behind ``drivers.interfaces``."""

from __future__ import annotations

import logging

import numpy as np

from nmsid.drivers.errors import DeviceRangeError
from nmsid.drivers.interfaces import (
    CheckedWaveform,
    StimulatorCapabilities,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.sim_backends.errors import (
    DeviceStateError,
    SimConfigError,
    StimulatorDisconnected,
    StimulatorFault,
)
from nmsid.sim_backends.faults import FaultKind
from nmsid.sim_backends.stim_stream import StreamingStimulator
from nmsid.sim_backends.world import SimWorld

log = logging.getLogger(__name__)

SIM_STG_CAPABILITIES = StimulatorCapabilities(
    n_channels=2, max_current_mA=16.0, resolution_mA=0.001, output_rate_Hz=50_000.0,
    model="SimSTG4002 (simulated)", serial="SIM-0001", firmware="sim")
"""What the simulated stimulator reports: 2 channels, 0-16 mA, 1 uA, 50 kHz (STG4002-like)."""


class SimStimulator(StreamingStimulator):
    """A current stimulator whose output drives the virtual participant.

    It is also a :class:`~nmsid.drivers.interfaces.HostStreamedStimulator` (closed loop:
    :mod:`nmsid.sim_backends.stim_stream`).

    Loading checks the waveform against the device (a :class:`CheckedWaveform` only, every
    sample within the device's range, envelope rate and carrier renderable) and quantises
    it to the device's resolution *downwards*, so a delivered current is never above the
    requested one (hence never above the waveform's ceiling). ``start`` is the trigger of
    the acquisition. ``stop_now`` is thread-safe, idempotent, never raises, and records the
    instant the output became zero.
    """

    def __init__(self, world: SimWorld,
                 capabilities: StimulatorCapabilities = SIM_STG_CAPABILITIES):
        self._w = world
        self._caps = capabilities
        self._state = StimulatorState.DISCONNECTED
        self._loaded: tuple[np.ndarray, np.ndarray, float, bool] | None = None

    # -- Stimulator interface ------------------------------------------------------------
    def connect(self) -> None:
        with self._w.lock:
            self._w.update()
            if self._w.stim_fault is not None:
                kind, text = self._w.stim_fault
                log.info("simulated stimulator reconnected after: %s", text)
                self._w.stim_fault = None
            self._state = StimulatorState.IDLE
            self._loaded = None

    def capabilities(self) -> StimulatorCapabilities:
        return self._caps

    def load(self, waveform: CheckedWaveform) -> None:
        if not isinstance(waveform, CheckedWaveform):
            raise TypeError(f"the stimulator only accepts a CheckedWaveform, got "
                            f"{type(waveform).__name__}")
        with self._w.lock:
            self._check_usable("load")
            state = self._current_state()
            if state is StimulatorState.RUNNING:
                raise DeviceStateError("load() while the stimulator is running; stop_now() "
                                       "or wait for the waveform to end")
            self._restore_stream_chunks()   # a stream left open ends here
            caps = self._caps
            for name, arr in (("I_ext_mA", waveform.I_ext_mA), ("I_flex_mA", waveform.I_flex_mA)):
                if arr.size and arr.max() > caps.max_current_mA:
                    raise DeviceRangeError(
                        f"{name} peaks at {arr.max():.3f} mA, above the stimulator's range "
                        f"0-{caps.max_current_mA:g} mA ({caps.model}); nothing was sent")
            if waveform.n_samples == 0:
                raise SimConfigError("the waveform is empty (0 samples); nothing was sent")
            if waveform.fs_Hz > caps.output_rate_Hz:
                raise SimConfigError(f"waveform envelope rate {waveform.fs_Hz:g} Hz exceeds "
                                     f"the stimulator's output rate {caps.output_rate_Hz:g} Hz")
            if not 0 < waveform.carrier_Hz <= caps.output_rate_Hz / 4:
                raise SimConfigError(f"carrier {waveform.carrier_Hz:g} Hz cannot be rendered: "
                                     f"must be in (0, {caps.output_rate_Hz / 4:g}] Hz")
            q_e = self._quantise(waveform.I_ext_mA)
            q_f = self._quantise(waveform.I_flex_mA)
            is_trial = bool(q_e.max() > 0 and q_f.max() > 0)
            w = self._w
            w.max_sent_mA[0] = max(w.max_sent_mA[0], float(q_e.max()))
            w.max_sent_mA[1] = max(w.max_sent_mA[1], float(q_f.max()))
            w.load_faults(w.n_runs, w.n_trials if is_trial else None)
            self._check_usable("load")
            self._loaded = (q_e, q_f, float(waveform.fs_Hz), is_trial)
            self._state = StimulatorState.LOADED

    def arm(self) -> None:
        with self._w.lock:
            self._check_usable("arm")
            if self._loaded is None or self._current_state() not in (
                    StimulatorState.LOADED, StimulatorState.ARMED):
                raise DeviceStateError(f"arm() needs a loaded waveform (state "
                                       f"{self._current_state().value})")
            self._state = StimulatorState.ARMED

    def start(self) -> None:
        with self._w.lock:
            self._check_usable("start")
            if self._state is not StimulatorState.ARMED or self._loaded is None:
                raise DeviceStateError(f"start() needs an armed waveform (state "
                                       f"{self._current_state().value})")
            q_e, q_f, fs, is_trial = self._loaded
            self._loaded = None
            self._w.start_run(q_e, q_f, fs, is_trial)
            self._state = StimulatorState.RUNNING
            self._stream_started()

    def stop_now(self) -> None:
        try:
            # the instant is recorded without waiting for the simulation lock: a
            # simulation in progress must not delay the stop
            self._w.request_stop()
            if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED,
                               StimulatorState.LOADED):
                self._state = StimulatorState.STOPPED
                self._loaded = None
        except Exception:  # never raise from the safety path; output is zero regardless
            log.exception("simulated stop_now failed to record its bookkeeping")

    def status(self) -> StimulatorStatus:
        with self._w.lock:
            self._w.update()
            state = self._current_state()
            run = self._w.run
            idx = -1
            active = False
            if state is StimulatorState.RUNNING and run is not None:
                active = True
                idx = int((self._w.now() - run.t_trigger_s) * run.fs_env_Hz)
            err = self._w.stim_fault[1] if self._w.stim_fault else ""
            return StimulatorStatus(state=state, output_active=active, error=err,
                                    sample_index=idx)

    def disconnect(self) -> None:
        self.stop_now()
        with self._w.lock:
            self._state = StimulatorState.DISCONNECTED

    # -- helpers -------------------------------------------------------------------------
    def _quantise(self, arr: np.ndarray) -> np.ndarray:
        res = self._caps.resolution_mA
        steps_per_mA = 1.0 / res
        k = np.floor(arr * steps_per_mA + 1e-6)
        if abs(steps_per_mA - round(steps_per_mA)) < 1e-9:
            q = k / round(steps_per_mA)   # exact decimal steps (6499 / 1000 -> 6.499)
        else:
            q = k * res
        return np.minimum(q, arr)   # never above what was asked (nor its ceiling)

    def _current_state(self) -> StimulatorState:
        w = self._w
        if self._state is StimulatorState.DISCONNECTED:
            return self._state
        if w.stim_fault is not None:
            return StimulatorState.ERROR
        if self._state is StimulatorState.RUNNING and not w.output_active_at(w.now()):
            self._state = StimulatorState.STOPPED
        return self._state

    def _check_usable(self, what: str) -> None:
        self._w.update()
        if self._state is StimulatorState.DISCONNECTED:
            raise DeviceStateError(f"{what}() on a disconnected stimulator; call connect()")
        if self._w.stim_fault is not None:
            kind, text = self._w.stim_fault
            cls = StimulatorDisconnected if kind is FaultKind.STIM_DISCONNECT else \
                StimulatorFault
            raise cls(f"{what}() refused: {text}; reconnect the stimulator (connect())")

    # -- for tests -----------------------------------------------------------------------
    @property
    def max_sent_mA(self) -> tuple[float, float]:
        """Largest current ever loaded on (extensor, flexor), after quantisation."""
        return float(self._w.max_sent_mA[0]), float(self._w.max_sent_mA[1])

    @property
    def max_delivered_mA(self) -> tuple[float, float]:
        """Largest current ever output on (extensor, flexor) during a simulated sample."""
        return float(self._w.max_delivered_mA[0]), float(self._w.max_delivered_mA[1])

    @property
    def output_zero_events(self):
        """When the output became zero by ``stop_now`` or a fault (clock and perf_counter)."""
        with self._w.lock:
            self._w.update()
            return list(self._w.output_zero)
