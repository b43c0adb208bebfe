"""Shared fixtures of the rig tests: a tiny fake rig (independent of ``sim_backends``) and
small configurations."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from nmsid.drivers.interfaces import (
    AcquisitionFlags,
    ForceChunk,
    RigDevices,
    StimulatorCapabilities,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.protocols.config import config_from_dict


class FakeClock:
    """Virtual time: sleep advances it; reads advance it by the chunk duration."""

    def __init__(self):
        self.t = 0.0
        self._lock = threading.Lock()

    def monotonic_s(self):
        return self.t

    def sleep(self, duration_s):
        with self._lock:
            self.t += max(0.0, duration_s)


class FakeStimulator:
    def __init__(self, max_current_mA=50.0):
        self.caps = StimulatorCapabilities(2, max_current_mA, 0.01, 100000.0, model="fake")
        self.loaded = None
        self.state = StimulatorState.DISCONNECTED
        self.received = []          # every waveform loaded
        self.error = ""
        self.stop_calls = 0
        self.output_active = False
        self.started = 0

    def connect(self):
        self.state = StimulatorState.IDLE

    def capabilities(self):
        return self.caps

    def load(self, wf):
        self.loaded = wf
        self.received.append(wf)
        self.state = StimulatorState.LOADED

    def arm(self):
        self.state = StimulatorState.ARMED

    def start(self):
        self.state = StimulatorState.RUNNING
        self.output_active = True
        self.started += 1

    def stop_now(self):
        self.stop_calls += 1
        self.output_active = False
        if self.state is not StimulatorState.ERROR:
            self.state = StimulatorState.STOPPED

    def status(self):
        if self.error:
            return StimulatorStatus(StimulatorState.ERROR, self.output_active, self.error)
        return StimulatorStatus(self.state, self.output_active)

    def disconnect(self):
        self.stop_now()
        self.state = StimulatorState.DISCONNECTED


class FakeAcquisition:
    """Force = k_e * max(0, I_ext - a_e) - k_f * max(0, I_flex - a_f) + noise-free."""

    def __init__(self, stim, clock, chunk=200, k_e=1.0, a_e=2.0, k_f=0.8, a_f=1.5):
        self.stim, self.clock, self.chunk = stim, clock, chunk
        self.k_e, self.a_e, self.k_f, self.a_f = k_e, a_e, k_f, a_f
        self.fs = 2000.0
        self.n = None
        self.pos = 0
        self.running = False
        self.faults = {}      # fault name -> (trial_start_count, sample index)

    def configure(self, fs_Hz):
        self.fs = fs_Hz
        return fs_Hz

    def start(self, n_samples=None, *, triggered=True):
        self.n, self.pos, self.running = n_samples, 0, True

    def _force(self, lo, hi):
        wf = self.stim.loaded
        Ie = np.asarray(wf.I_ext_mA[lo:hi])
        If = np.asarray(wf.I_flex_mA[lo:hi])
        return self.k_e * np.maximum(0, Ie - self.a_e) - self.k_f * np.maximum(0, If - self.a_f)

    def read(self, timeout_s):
        if not self.running or not self.stim.output_active or self.pos >= (self.n or 0):
            self.clock.sleep(timeout_s)
            return None
        lo = self.pos
        hi = min(self.n, lo + self.chunk)
        flags = AcquisitionFlags()
        f = self._force(lo, hi)
        trial_no = self.stim.started
        for name, (when, k) in list(self.faults.items()):
            if when == trial_no and lo <= k < hi:
                if name == "stall":
                    self.clock.sleep(timeout_s)
                    return None
                if name == "over_range":
                    flags = AcquisitionFlags(over_range=True, detail="injected")
                if name == "spike":
                    f = f.copy()
                    f[k - lo] = 1000.0
                if name == "stim_error":
                    self.stim.error = "injected error"
                if name == "empty_fault":  # no samples, only a flag (e.g. a CAIO error)
                    self.clock.sleep(timeout_s)
                    return ForceChunk(start_index=lo, force_N=np.zeros(0),
                                      flags=AcquisitionFlags(sensor_fault=True,
                                                             detail="A/D error 7"))
                if name == "estop":
                    threading.Thread(target=self.estop_fn).start()
                    import time
                    time.sleep(0.05)
        self.pos = hi
        self.clock.sleep((hi - lo) / self.fs)
        return ForceChunk(start_index=lo, force_N=f, flags=flags)

    def stop(self):
        self.running = False

    def close(self):
        pass


@pytest.fixture
def fake_rig():
    """Factory: ``fake_rig(**acq_kwargs) -> RigDevices`` over the fake devices."""
    def make(**kw):
        clock = FakeClock()
        stim = FakeStimulator()
        acq = FakeAcquisition(stim, clock, **kw)
        return RigDevices(stimulator=stim, acquisition=acq, estop=None, clock=clock,
                          backend="fake")
    return make


@pytest.fixture
def small_config():
    """Factory: a short protocol (2 levels x 2 repeats, 0.5 s steady + 1 s chirp)."""
    def make(**over):
        d = {"participant": "T01", "seed": 7,
             "protocol": {"sE_levels": [0.4, 0.8], "repeats": 2, "steady_s": 0.5,
                          "chirp_s": 1.0, "rest_s": 0.0},
             "calibration": {"hold_s": 0.2, "baseline_s": 0.1, "ceiling_ext_mA": 20.0,
                             "ceiling_flex_mA": 20.0}}
        for k, v in over.items():
            if isinstance(v, dict):
                d.setdefault(k, {}).update(v)
            else:
                d[k] = v
        return config_from_dict(d)
    return make
