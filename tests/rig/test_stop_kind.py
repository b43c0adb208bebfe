"""Which stop ends a block: the save stop for an ordinary end, the immediate stop for a trip.

STG4002 (McsUsbNet 5.3.15, ``SendStop`` with ``STOP_OPTION_SAVESTOP``): the save stop lets
the running biphasic carrier period finish, so no net charge is left; the immediate stop
may cut a period mid-phase (up to 5.09 uC at 16 mA, issue 25) and is only for an E-stop,
a trip or a fault (``rig.stimulation.run_block``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from nmsid.drivers.interfaces import CheckedWaveform, PeriodSafeStop
from nmsid.protocols.interlock_settings import InterlockConfig
from nmsid.rig.safety import Interlock
from nmsid.rig.stimulation import run_block
from nmsid.sim_backends import make_sim_rig


class SaveStopSpy:
    """The simulated stimulator with the STG's save stop, recording which stop ran."""

    def __init__(self, inner):
        self._inner = inner
        self.stops: list[str] = []

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def stop_after_period(self) -> None:
        self.stops.append("after_period")
        self._inner.stop_now()

    def stop_now(self) -> None:
        self.stops.append("now")
        self._inner.stop_now()


def _block(*, estop_after_s: float | None = None, abort: bool = False):
    rig = make_sim_rig(seed=1)
    spy = SaveStopSpy(rig.stimulator)
    devices = dataclasses.replace(rig, stimulator=spy)
    devices.stimulator.connect()
    assert isinstance(spy, PeriodSafeStop)
    interlock = Interlock(InterlockConfig(), spy)
    fs = 2000.0
    env = np.full(int(0.5 * fs), 2.0)
    wf = CheckedWaveform(env, env, fs, 1000.0, 5.0, 5.0)
    acq_fs = devices.acquisition.configure(fs)
    n = int(0.5 * acq_fs)

    def should_stop() -> str:
        t = devices.clock.monotonic_s()
        if estop_after_s is not None and t - t0 > estop_after_s:
            interlock.estop("operator E-stop")
        if abort and t - t0 > 0.1:
            return "operator abort"
        return ""

    t0 = devices.clock.monotonic_s()
    try:
        result = run_block(devices, interlock, wf, n, should_stop=should_stop)
        stops = list(spy.stops)   # the block's own stops, before the rig is closed
    finally:
        devices.close()
    return stops, result


def test_an_ordinary_end_uses_the_save_stop():
    stops, result = _block()
    assert result.abort_reason == "" and stops == ["after_period"]


def test_an_operator_abort_uses_the_save_stop():
    stops, result = _block(abort=True)
    assert "abort" in result.abort_reason and stops == ["after_period"]


def test_an_estop_uses_the_immediate_stop_only():
    stops, result = _block(estop_after_s=0.1)
    assert "E-stop" in result.abort_reason or "estop" in result.abort_reason.lower()
    assert "after_period" not in stops and "now" in stops
