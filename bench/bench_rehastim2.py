"""E-stop to the stimulator's stop, per stimulator kind, on the fake hardware at real speed.

The same engine, interlock and fake CAIO force chain drive (a) the fake MCS STG4002
(McsUsbNet, download mode; the baseline) and (b) the fake Hasomed RehaStim2 (ScienceMode2
bytes over a fake serial port, pulses streamed by the host). While a trial stimulates,
another thread presses the engine's E-stop at a random moment and records the bench clock
just before the call; the fake device records when it processed the stop (the STG's
``SendStop``; the RehaStim2's StopChannelListMode packet). Like for like: the same trials,
the same clock, the same presser.

Also reported for the RehaStim2: updates the host skipped because it fell behind the
trial's time base (``updates_skipped_late`` of each trial's ``stimulation_json``).

    python bench/bench_rehastim2.py        # 20 trips per kind
"""

from __future__ import annotations

import json
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.fake_hardware import load_fake  # noqa: E402
from nmsid.drivers.hardware import make_hw_rig  # noqa: E402
from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.protocols.session_file import read_session  # noqa: E402
from nmsid.rig.engine import Engine, EngineObserver  # noqa: E402
from nmsid.rig.states import State  # noqa: E402

GOAL_MS = 10.0
STIMULATORS = {
    "stg4002": ['kind = "stg4002"'],
    "rehastim2": ['kind = "rehastim2"', 'port = "COM5"'],
}


def _hw_file(folder: Path, kind: str) -> Path:
    lines = ["[rig]", "fake = true", "fake_speed = 1.0", "[stimulator]", *STIMULATORS[kind],
             "ceiling_ext_mA = 16.0", "ceiling_flex_mA = 16.0",
             "[acquisition]", 'kind = "caio"', "[sensor]", "sync_channel = 6",
             "[sensor.channels]", "Fx = 0", "[sensor.rated]", "Fx = 500.0",
             "[sensor.rated_output_V]", "Fx = 1.0",   # manual 4.1
             "[sensor.offset_V]", "Fx = 1.5"]
    path = folder / f"{kind}.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _stop_time(devices, kind: str) -> float | None:
    if kind == "rehastim2":
        stops = devices.acquisition._stack.stimulator_fake.stops
        return stops[-1] if stops else None
    return load_fake("fake_mcs_usb").registry().devices[-1].stopped_at


def _measure(kind: str, n_trips: int, seed: int = 1):
    folder = Path(tempfile.mkdtemp(prefix=f"nmsid-bench-{kind}-"))
    devices = make_hw_rig(_hw_file(folder, kind))
    bench = devices.clock.bench
    cfg = config_from_dict({
        "participant": "BENCH", "seed": seed, "interlock": {"stall_timeout_s": 2.0},
        "protocol": {"sE_levels": [round(0.3 + 0.05 * k, 2) for k in range(15)],
                     "repeats": int(np.ceil((n_trips + 5) / 15)), "steady_s": 0.2,
                     "chirp_s": 0.5, "rest_s": 0.0},
        "calibration": {"manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.0, "Ifmin_mA": 2.0,
                                   "Ifmax_mA": 8.0}}})
    stimulating = threading.Event()
    rng = np.random.default_rng(seed)
    pairs: list[tuple[float, float | None]] = []
    calls: list[float] = []

    class Operator(EngineObserver):
        def on_state(self, old, new, reason):
            if new is State.STIMULATING:
                stimulating.set()
            elif new is State.TRIPPED:
                if calls and len(pairs) < len(calls):
                    pairs.append((calls[-1], _stop_time(devices, kind)))
                eng.commands.rearm()

    path = folder / "s.h5"
    eng = Engine(cfg, devices, path, observer=Operator())

    def presser():
        while len(calls) < n_trips:
            if not stimulating.wait(2.0):
                if eng.state in (State.FINISHED, State.ABORTED):
                    return
                continue
            stimulating.clear()
            time.sleep(rng.uniform(0.05, 0.4))
            if eng.state is not State.STIMULATING:
                continue
            calls.append(bench.now())
            eng.commands.estop("bench")
        eng.commands.abort()

    th = threading.Thread(target=presser, daemon=True)
    th.start()
    try:
        eng.run()
    finally:
        th.join(5.0)
        devices.close()
    lat = np.asarray([(s - c) * 1000.0 for c, s in pairs if s is not None and s >= c])
    skipped = []
    if kind == "rehastim2":
        for t in read_session(path).trials:
            stim = t.extra_attrs.get("stimulation_json")
            if stim:
                stim = json.loads(stim) if isinstance(stim, str) else stim
                skipped.append((stim["updates_skipped_late"], stim["updates_planned"]))
    return lat, len(pairs), skipped


def main(n_trips: int = 20) -> None:
    logging.disable(logging.WARNING)
    print(f"E-stop -> the device processed its stop, fake hardware at real speed, "
          f"{n_trips} trips per kind (same engine, interlock, CAIO chain, presser)")
    print(f"{'stimulator':28s} {'n':>4s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} "
          f"{'vs STG p50':>10s} {'goal':>8s}")
    base = None
    for kind, label in (("stg4002", "fake STG4002 (baseline)"),
                        ("rehastim2", "fake RehaStim2 (ScienceMode2)")):
        lat, _n, skipped = _measure(kind, n_trips)
        if lat.size:
            p50, p99, mx = np.percentile(lat, 50), np.percentile(lat, 99), lat.max()
        else:
            p50 = p99 = mx = float("nan")
        base = p50 if base is None else base
        verdict = "met" if lat.size and p99 < GOAL_MS else "missed"
        print(f"{label:28s} {lat.size:4d} {p50:8.3f} {p99:8.3f} {mx:8.3f} "
              f"{p50 / base if base else float('nan'):9.2f}x {'p99 < 10':>8s} {verdict}",
              flush=True)
        if skipped:
            late = sum(s for s, _ in skipped)
            planned = sum(p for _, p in skipped)
            print(f"  RehaStim2 updates skipped late (host behind the time base): {late} of "
                  f"{planned} planned over {len(skipped)} trials", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
