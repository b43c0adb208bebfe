"""The dry run's loop-back on the fake bench: a dummy-load resistor and two spare A/D inputs.

Wiring modelled (as ``docs/hardware.md`` describes it for the real rig): the STG output of
the tested channel drives a resistor of ``load_ohm``; the voltage over it goes to a spare
A/D input (differential); the STG sync output goes to another (and, as always, to the
A/D's trigger input, so sample 0 is the sync's rising edge). The A/D is a 16-bit converter
on +-10 V with ``noise_V`` rms input noise; its samples are taken on the bench clock from
what the fake STG really played (``FakeStgHardware.current_at`` / ``sync_at``).

``actual_ohm`` (default: ``load_ohm``) is the resistor really fitted: a test sets it apart
from ``load_ohm`` to see the dry run fail its amplitude check.
"""

from __future__ import annotations

import numpy as np

from nmsid.testing.fakes.fake_mcs_usb import registry


class BenchLoopback:
    """Record the monitor voltage, the sync and the time base of one triggered trial."""

    RANGE_V = 10.0
    BITS = 16

    def __init__(self, bench, *, channel: int, sync_out: int, load_ohm: float,
                 actual_ohm: float | None = None, noise_V: float = 1e-3, seed: int = 0):
        self.bench = bench
        self.channel, self.sync_out = channel, sync_out    # 0-based STG numbering
        self.load_ohm = float(load_ohm)
        self.actual_ohm = float(actual_ohm if actual_ohm is not None else load_ohm)
        self.noise_V = noise_V
        self.rng = np.random.default_rng(seed)

    def _quantise(self, v: np.ndarray) -> np.ndarray:
        lsb = 2 * self.RANGE_V / 2 ** self.BITS
        return np.clip(np.round(v / lsb) * lsb, -self.RANGE_V, self.RANGE_V - lsb)

    def record(self, n_samples: int, fs_Hz: float) -> tuple[np.ndarray, np.ndarray]:
        """``(monitor_V, sync_V)``: ``n_samples`` at ``fs_Hz`` from the last sync edge."""
        hw = registry().hardware[0]
        t0 = hw.started_at
        if t0 is None:
            raise RuntimeError("loop-back: the fake STG never started (no sync edge)")
        # sample 0 = the A/D's trigger; the sync edge is seen a fraction of a sample later
        t = t0 + np.arange(n_samples) / fs_Hz
        current_A = hw.current_at(self.channel, t) * 1e-9
        mon = current_A * self.actual_ohm + self.noise_V * self.rng.standard_normal(n_samples)
        sync = hw.sync_at(self.sync_out, t) * self.bench.sync_high_V
        return self._quantise(mon), self._quantise(sync)
