"""What the simulated rig remembers: stimulator runs, acquisitions, output-zero instants,
scheduled sample faults and the block of samples simulated ahead."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.sim_backends.errors import DeviceStateError
from nmsid.sim_backends.faults import Fault


@dataclass
class StimRun:
    """One start of the stimulator (a calibration step or a trial)."""

    index: int
    trial: int | None
    """Trial index (runs delivering current on both channels), None for one-muscle runs."""
    I_ext_mA: np.ndarray
    """Delivered (quantised) envelope, at ``fs_env_Hz``."""
    I_flex_mA: np.ndarray
    fs_env_Hz: float
    t_trigger_s: float
    N_trigger: int
    n_out: int
    """Acquisition samples the waveform lasts."""
    N_stop: int | None = None
    stop_reason: str = ""
    bound: bool = False
    """An acquisition took this run's trigger as its sample 0."""

    @property
    def N_end(self) -> int:
        """First absolute sample with the output at zero."""
        end = self.N_trigger + self.n_out
        return end if self.N_stop is None else max(self.N_trigger, min(end, self.N_stop))

    @property
    def duration_s(self) -> float:
        return self.I_ext_mA.size / self.fs_env_Hz


@dataclass
class RunRecord:
    """What the stimulator did in one run (kept for the whole session, without envelopes)."""

    index: int
    trial: int | None
    t_trigger_s: float
    N_trigger: int
    n_planned: int
    N_end: int | None = None
    stop_reason: str = ""
    max_ext_mA: float = 0.0
    max_flex_mA: float = 0.0


@dataclass
class OutputZero:
    """The instant the stimulator output became zero other than by the waveform's end."""

    reason: str
    clock_s: float
    perf_counter_s: float
    sample_index: int | None
    run_index: int | None


@dataclass
class SampleFault:
    fault: Fault
    t_s: float
    N: int
    N_end: int
    done: bool = False


@dataclass
class SimBlock:
    """Samples simulated ahead of the acquisition, and how to undo them."""

    N0: int
    N1: int
    snapshot: tuple
    I_e: np.ndarray
    I_f: np.ndarray
    spike: np.ndarray | None
    sync: np.ndarray
    force_N: np.ndarray
    wrench: np.ndarray
    over: np.ndarray | None
    peak_e: float
    peak_f: float


@dataclass
class AcqRun:
    """One acquisition from ``start`` to ``stop``."""

    triggered: bool
    n_samples: int | None
    t_start_s: float
    N0: int | None = None
    t0_s: float | None = None
    next_k: int = 0
    run_index: int | None = None
    stall_end_s: float | None = None
    stalled: bool = False
    lost_detail: str = ""
    """Set when samples were skipped (dropout, buffer overflow): the next chunk carries
    ``flags.overrun`` with this detail."""

    @property
    def waiting(self) -> bool:
        return self.N0 is None

    @property
    def origin(self) -> tuple[int, float]:
        """``(N0, t0_s)``: the absolute sample and clock time of sample 0 (once triggered).

        Raises
        ------
        DeviceStateError
            While the acquisition still waits for its trigger.
        """
        if self.N0 is None or self.t0_s is None:
            raise DeviceStateError("the acquisition has not been triggered yet")
        return self.N0, self.t0_s

    @property
    def done(self) -> bool:
        return self.n_samples is not None and self.next_k >= self.n_samples
