"""Dry-run figures on the fake rig: ``nmsid probe --dry-run``'s checks through the real CAIO
and NI drivers (force, sync and the dummy-load monitor in one triggered scan).

No hardware here: the fake STG's output crosses a simulated resistor into the fake A/D's
monitor input (1 mV rms input noise, 16 bits on +-10 V); the fake CAIO converts channels
10 us apart (Contec's data sheet), the fake NI at an 80 kHz convert clock (a stand-in),
spread over the sample period when the channels need it. For each chain, monitor input
and rate: every check's figure, and the onset the check would report WITHOUT adding back
the A/D's known scan delay (the baseline: the same record and estimator, the
multiplexer's delay ignored). Then two wiring faults that must fail: a 1.5 kOhm resistor
declared as 1 kOhm, and the resistor on the other STG channel. Then the STG's streamed
trial (issue 37 item 8: a slow sine streamed while it plays, each carrier period's
lock-in amplitude against ``stream.commands``) beside the downloaded trial's amplitude
error on the same chain (the baseline), and two stream faults that must fail: a 10 % gain
error of the delivered current, and a stream that runs dry after 0.3 s. Every trial is a
plan run by the engine (``rig/dry_run.py``); the fake bench runs in real time (the
streamed trial writes its updates while it plays).

    python bench/run.py dry_run
"""

from __future__ import annotations

import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.dry_run import DryRunSettings  # noqa: E402
from nmsid.drivers.hardware import build_devices, with_monitor  # noqa: E402
from nmsid.drivers.hw_config import parse_hw_config  # noqa: E402
from nmsid.drivers.registry import stimulator_kind  # noqa: E402
from nmsid.rig.dry_run import run_dry_run  # noqa: E402
from nmsid.testing.fakes import fake_stg_streaming  # noqa: E402

AXES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


def hw_file(kind: str, monitor: int) -> dict:
    acquisition: dict = {"kind": kind, "monitor_channel": monitor}
    if kind == "nidaq" and monitor >= 8:
        # AI8-15 exist as single-ended inputs only (in DIFF they pair with AI0-7)
        acquisition["nidaq"] = {"terminal_config": "RSE"}
    return {"rig": {"fake": True, "fake_speed": 1.0},
            "acquisition": acquisition,
            "sensor": {"channels": {a: i for i, a in enumerate(AXES)}, "sync_channel": 6,
                       "rated": dict(zip(AXES, (500.0, 500.0, 1000.0, 10.0, 10.0, 10.0),
                                         strict=True)),
                       "rated_output_V": dict.fromkeys(AXES, 1.0),   # manual 4.1
                       "offset_V": dict.fromkeys(AXES, 1.5)}}


def dry_run(kind: str, monitor: int, fs_Hz: float, *, wired=0, ohm=1000.0, roles=None):
    cfg = with_monitor(parse_hw_config(hw_file(kind, monitor), f"bench {kind}"))
    devices = build_devices(cfg)
    lines: list[str] = []
    t0 = time.perf_counter()
    try:
        devices.clock.bench.dummy_load = (wired, ohm)
        with tempfile.TemporaryDirectory() as folder:
            ok = run_dry_run(devices, DryRunSettings(monitor_fs_Hz=fs_Hz),
                             stimulator_kind(cfg.stimulator).dry_run, out=lines.append,
                             monitor_channel=monitor, session_dir=folder, roles=roles)
    finally:
        devices.close()
    return ok, "\n".join(lines), time.perf_counter() - t0


def figure(text: str, name: str, pattern: str) -> float:
    line = next((x for x in text.splitlines() if f"] {name}:" in x), "")
    m = re.search(pattern, line)
    return float(m.group(1)) if m else float("nan")


def main() -> None:
    print(__doc__.split("\n\n")[0])
    print()
    head = (f"{'chain':6} {'input':>5} {'kHz':>4} {'verdict':>7} {'onset us':>9} "
            f"{'uncorr. us':>10} {'amp err %':>9} {'carrier Hz':>10} {'env r':>7} "
            f"{'net nC/per':>10} {'wall s':>6}")
    print(head)
    print("-" * len(head))
    worst_onset, worst_plain = 0.0, 0.0
    for kind, monitor, fs in (("caio", 7, 10e3), ("caio", 9, 10e3), ("nidaq", 7, 10e3),
                              ("nidaq", 7, 20e3), ("nidaq", 15, 20e3)):
        ok, text, wall = dry_run(kind, monitor, fs)
        onset_ms = figure(text, "onset", r"current ([+-][0-9.]+) ms")
        delay_ms = figure(text, "onset", r"scan delay ([0-9.]+) ms")
        delay_ms = 0.0 if delay_ms != delay_ms else delay_ms
        plain_ms = onset_ms - delay_ms
        worst_onset = max(worst_onset, abs(onset_ms))
        worst_plain = max(worst_plain, abs(plain_ms))
        print(f"{kind:6} {'AI' + str(monitor):>5} {fs / 1e3:4.0f} {'OK' if ok else 'FAIL':>7} "
              f"{onset_ms * 1e3:+9.1f} {plain_ms * 1e3:+10.1f} "
              f"{figure(text, 'amplitude', r'[(]([0-9.]+) %'):9.2f} "
              f"{figure(text, 'carrier', r'([0-9.]+) Hz'):10.2f} "
              f"{figure(text, 'envelope', r'r = ([0-9.]+)'):7.4f} "
              f"{figure(text, 'charge balance', r'worst net ([0-9.]+) nC'):10.3f} {wall:6.1f}")
    print(f"worst |onset| with the scan delay added back: {worst_onset * 1e3:.1f} us; "
          f"without adding it back: {worst_plain * 1e3:.1f} us "
          f"(ratio {worst_plain / max(worst_onset, 1e-9):.1f}x; limit 100 us: "
          f"{'met' if worst_onset * 1e3 <= 100 else 'missed'})")
    print()
    faults = [("1.5 kOhm fitted, 1 kOhm declared", {"ohm": 1500.0}, "amplitude"),
              ("resistor on the other STG channel", {"wired": 1}, "amplitude")]
    caught = 0
    for label, kw, check in faults:
        ok, text, _ = dry_run("caio", 7, 10e3, **kw)
        failed = [m.group(1) for m in re.finditer(r"\[FAIL\] ([a-z ]+):", text)]
        caught += (not ok) and check in failed
        print(f"fault: {label:36} verdict {'OK' if ok else 'FAIL'}; failed checks: "
              f"{', '.join(failed) or 'none'}")
    print(f"wiring faults caught: {caught}/{len(faults)} "
          f"({'met' if caught == len(faults) else 'missed'}: every one)")
    streamed()


def streamed() -> None:
    """The STG's streamed trial against the downloaded one, and two stream faults."""
    print()
    ok_d, text_d, _ = dry_run("caio", 7, 10e3)
    ok_s, text_s, wall = dry_run("caio", 7, 10e3, roles=["streamed"])
    base = figure(text_d, "amplitude", r"[(]([0-9.]+) %")
    amp = figure(text_s, "stream: amplitude", r"[(]([0-9.]+) %")
    print(f"STG streamed trial (caio AI7, 10 kHz): verdict {'OK' if ok_s else 'FAIL'}; "
          f"amplitude error {amp:.2f} % of 2 mA per carrier period vs the downloaded "
          f"trial's {base:.2f} % (baseline, verdict {'OK' if ok_d else 'FAIL'}); envelope r "
          f"{figure(text_s, 'stream: envelope', r'r = ([0-9.]+)'):.4f}; wall {wall:.1f} s "
          f"(limit 5 %: {'met' if amp <= 5 else 'missed'})")
    cls = fake_stg_streaming.CStg200xStreamingNet
    current_at, arrival = cls.current_at, cls._arrival

    def low(self, ch, t):
        return 0.9 * current_at(self, ch, t)

    def starved(self, ch, limit=None):
        arr = arrival(self, ch, limit)
        return np.where(self._head + np.arange(len(arr)) >= 15_000, np.inf, arr)
    caught = 0
    faults = (("delivered current 10 % low", "current_at", low),
              ("stream runs dry after 0.3 s", "_arrival", starved))
    for label, name, fn in faults:
        setattr(cls, name, fn)
        try:
            ok, text, _ = dry_run("caio", 7, 10e3, roles=["streamed"])
        finally:
            cls.current_at, cls._arrival = current_at, arrival
        failed = [m.group(1) for m in re.finditer(r"\[FAIL\] ([a-z: ]+):", text)]
        caught += (not ok) and "stream: amplitude" in failed
        print(f"fault: {label:36} verdict {'OK' if ok else 'FAIL'}; failed checks: "
              f"{', '.join(failed) or 'none'}")
    print(f"stream faults caught: {caught}/{len(faults)} "
          f"({'met' if caught == len(faults) else 'missed'}: every one)")


if __name__ == "__main__":
    with tempfile.TemporaryDirectory():
        main()
