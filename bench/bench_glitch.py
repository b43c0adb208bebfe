"""Time from a USB glitch between trials to the resumed session (issue 16).

On the fake hardware stack (real-time fakes: the Leptrino emulator on a pseudo-terminal,
the fake CAIO library, the fake STG), the force sensor's USB link is pulled and restored
right after a trial ends (the emulator's ``unplug(); replug()``: the old port handle is
dead, a new one must be opened). Measured with ``perf_counter``:

* in-process recovery (this issue): from the glitch to the next ``trial_start`` (found
  before the next trial, reconnected, the operator's confirmation answered at once); the
  part up to the ``resumed`` event is printed too;
* baseline, the same process doing what the operator had to do before: the session ends
  (``on_device_glitch`` says no), the devices are closed and built again, and a new engine
  resumes the file (``--resume``), up to its first ``trial_start`` (program start-up and the
  operator's typing are not counted, so the baseline is a lower bound).

The same on the simulated rig (fast clock) for the acquisition and the stimulator.

    python bench/bench_glitch.py
"""

from __future__ import annotations

import logging
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.hardware import make_hw_rig  # noqa: E402
from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy  # noqa: E402
from nmsid.sim_backends import Fault, FaultKind, make_sim_rig  # noqa: E402

REPEATS = 3


def _cfg(fs_Hz: float, rest_s: float = 0.0):
    return config_from_dict({
        "participant": "BENCH", "seed": 1, "interlock": {"stall_timeout_s": 2.0},
        "protocol": {"sE_levels": [0.5, 0.9], "repeats": 1, "steady_s": 0.3, "chirp_s": 0.5,
                     "rest_s": rest_s, "fs_Hz": fs_Hz},
        "calibration": {"manual": {"Iemin_mA": 2.5, "Iemax_mA": 7.0, "Ifmin_mA": 2.5,
                                   "Ifmax_mA": 7.0}}})


def _hw_config(path: Path) -> Path:
    path.write_text("\n".join([
        "[rig]", "fake = true", "fake_speed = 1.0", "[stimulator]", "ceiling_ext_mA = 16.0",
        "ceiling_flex_mA = 16.0", "[acquisition]", 'kind = "leptrino"', "fs_Hz = 1200.0",
        "[acquisition.leptrino]", 'port = "COM5"',
        "[estop]", 'kind = "none"']) + "\n")
    return path


class _Timer(EngineObserver):
    """Pulls the sensor's USB link after trial 0; notes when the session resumed."""

    def __init__(self, devices):
        self.devices = devices
        self.t_glitch = self.t_resumed = self.t_trial = self.t_next = None

    def on_trial_finished(self, index, trial):
        if index == 0 and self.t_glitch is None:
            emu = self.devices.acquisition._stack.emulator
            self.t_glitch = time.perf_counter()
            emu.unplug()
            emu.replug()

    def on_event(self, event):
        if event.kind == "resumed" and self.t_resumed is None:
            self.t_resumed = time.perf_counter()
        if event.kind == "trial_start" and self.t_trial is None:
            self.t_trial = time.perf_counter()
        elif event.kind == "trial_start" and self.t_glitch is not None and self.t_next is None:
            self.t_next = time.perf_counter()


def _fake_in_process(tmp: Path) -> tuple[float, float]:
    devices = make_hw_rig(_hw_config(tmp / "hw.toml"))
    timer = _Timer(devices)
    try:
        s = Engine(_cfg(1200.0), devices, tmp / "a.h5", observer=timer,
                   trip_policy=TripPolicy.END_SESSION,
                   on_device_glitch=lambda what, ok: ok).run()
    finally:
        devices.close()
    assert s.n_completed == 2 and timer.t_resumed is not None, s.ended_by
    return timer.t_next - timer.t_glitch, timer.t_resumed - timer.t_glitch


def _fake_restart(tmp: Path) -> float:
    devices = make_hw_rig(_hw_config(tmp / "hw.toml"))
    timer = _Timer(devices)
    path = tmp / "b.h5"
    try:
        s = Engine(_cfg(1200.0), devices, path, observer=timer,
                   trip_policy=TripPolicy.END_SESSION,
                   on_device_glitch=lambda what, ok: False).run()
    finally:
        devices.close()
    assert s.n_completed == 1, s.ended_by
    devices = make_hw_rig(_hw_config(tmp / "hw.toml"))
    again = _Timer(devices)
    try:
        s = Engine(None, devices, path, resume=True, observer=again,
                   trip_policy=TripPolicy.END_SESSION).run()
    finally:
        devices.close()
    assert s.n_completed >= 1 and again.t_trial is not None, s.ended_by
    return again.t_trial - timer.t_glitch


def _sim(kind: FaultKind, tmp: Path, resume: bool):
    trial_s = 0.8
    fault = Fault(kind, trial=0, at_s=trial_s + 0.5)
    marks: dict = {}

    class Obs(EngineObserver):
        def on_event(self, event):
            if event.kind in ("device_glitch", "resumed", "trial_start"):
                marks.setdefault(event.kind, []).append(time.perf_counter())

    path = tmp / f"{kind.value}-{resume}.h5"
    s = Engine(_cfg(2000.0, rest_s=1.0), make_sim_rig(seed=1, faults=[fault]), path,
               observer=Obs(), trip_policy=TripPolicy.END_SESSION,
               on_device_glitch=lambda what, ok: ok if resume else False).run()
    if resume:
        assert s.n_completed == 2, s.ended_by
        t0 = marks["device_glitch"][0]
        return (next(t for t in marks["trial_start"] if t > t0) - t0,
                marks["resumed"][0] - t0)
    marks.pop("trial_start", None)
    Engine(None, make_sim_rig(seed=1), path, resume=True, observer=Obs(),
           trip_policy=TripPolicy.END_SESSION).run()
    return marks["trial_start"][0] - marks["device_glitch"][0]


def _median(values) -> float:
    return statistics.median(values)


def main() -> None:
    logging.basicConfig(level=logging.ERROR)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for r in range(REPEATS):
            tmp = Path(d) / f"r{r}"
            tmp.mkdir()
            rows.append(("fake Leptrino (USB unplug/replug)", *_fake_in_process(tmp),
                         _fake_restart(tmp)))
            for kind in (FaultKind.SENSOR_DISCONNECT, FaultKind.STIM_DISCONNECT):
                rows.append((f"sim {kind.value} (fast clock)", *_sim(kind, tmp, True),
                             _sim(kind, tmp, False)))
    print("time from a USB glitch between trials to the next trial's start "
          f"(median of {REPEATS}, wall clock)")
    for name in dict.fromkeys(r[0] for r in rows):
        ins = _median([r[1] for r in rows if r[0] == name])
        res = _median([r[2] for r in rows if r[0] == name])
        base = _median([r[3] for r in rows if r[0] == name])
        print(f"  {name:36s} in-process {ins * 1e3:7.1f} ms (resumed after "
              f"{res * 1e3:6.1f} ms)   end + --resume {base * 1e3:7.1f} ms   "
              f"ratio {base / ins:5.1f}x")


if __name__ == "__main__":
    main()
