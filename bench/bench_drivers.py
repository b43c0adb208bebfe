"""Driver figures: STG download rendering, stop latency, Leptrino codec and pty stream.

Measured against the fakes in testing/fakes (no hardware here), so they are the
host-side costs of the drivers, not the devices' own latencies:

* rendering + quantising + checking one paper trial (15 s, 2 channels, 50 kHz output) and
  the size of the download (points, estimated device memory);
* ``stop_now()`` call-to-return time on the fake STG while "running" (p50 / p99 over 200);
* Leptrino frame decoding throughput (frames/s) against the sensor's 1200 frames/s;
* the Leptrino driver reading the emulator through a real pseudo-terminal for 2 s:
  records/s received and records lost;
* the Leptrino record rate MEASURED at connect (emulator streaming at 1000 Hz, stating no
  rate), its error against the true rate, and the ratio to the error of the rate the old
  driver assumed (1200 Hz); target: within 1 %;
* ``nmsid probe --check-assembly`` on the real McsUsbNet 5.3.15 (needs mono), wall time
  against a bare ``python -c "import nmsid"`` in the same process tree.

    python bench/run.py drivers
"""

from __future__ import annotations

import os
import statistics
import struct
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.fake_hardware import load_fake  # noqa: E402
from nmsid.drivers.interfaces import CheckedWaveform  # noqa: E402
from nmsid.drivers.leptrino import LeptrinoAcquisition, LeptrinoSensor  # noqa: E402
from nmsid.drivers.leptrino_protocol import FrameDecoder, encode_frame  # noqa: E402
from nmsid.drivers.stg4002 import BYTES_PER_POINT, Stg4002Stimulator  # noqa: E402
from nmsid.drivers.stg_waveform import check_rendered, render_channel  # noqa: E402


def paper_trial(fs=2000.0):
    t = np.arange(int(15 * fs)) / fs
    f0, f1, T = 1.0, 10.0, 10.0
    k = np.log(f1 / f0) / T
    phase = 2 * np.pi * f0 * (np.exp(k * np.clip(t - 5, 0, None)) - 1) / k
    rE = np.where(t < 5, 0.5, 0.5 + 0.5 * np.sin(phase))
    I_ext = 3 + rE * 6
    I_flex = 3 + (1 - rE) * 6
    return CheckedWaveform(I_ext, I_flex, fs, 1000.0, 16.0, 16.0)


def bench_render(rows):
    wf = paper_trial()
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        chans = [render_channel(env, wf.fs_Hz, 1000.0, 50_000.0, 500.0)
                 for env in (wf.I_ext_mA, wf.I_flex_mA)]
        for c in chans:
            check_rendered(c, 16.0, "bench")
        times.append(time.perf_counter() - t0)
    points = sum(c.n_points for c in chans)
    rows.append(("render+quantise+check, 15 s trial, 2 ch", f"{min(times) * 1e3:.0f} ms",
                 "best of 3"))
    rows.append(("download size", f"{points} points",
                 f"~{points * BYTES_PER_POINT / 1e6:.1f} MB of 64 MB (est. 8 B/point)"))
    # whole load() through the fake .NET layer (array conversion included)
    mods = {}
    mcs = load_fake("fake_mcs_usb")
    mcs.install(modules=mods)
    saved = {k: sys.modules.get(k) for k in mods}
    sys.modules.update(mods)
    try:
        stim = Stg4002Stimulator(ceiling_ext_mA=16, ceiling_flex_mA=16)
        stim.connect()
        t0 = time.perf_counter()
        stim.load(wf)
        rows.append(("Stg4002Stimulator.load() on the fake McsUsbNet",
                     f"{(time.perf_counter() - t0) * 1e3:.0f} ms", "incl. list -> Array"))
        lat = []
        for _ in range(200):
            stim._state = stim._state.__class__.RUNNING
            t0 = time.perf_counter()
            stim.stop_now()
            lat.append(time.perf_counter() - t0)
        lat.sort()
        rows.append(("stop_now() call -> return (fake device)",
                     f"p50 {lat[100] * 1e6:.0f} us, p99 {lat[197] * 1e6:.0f} us",
                     "host side only"))
        stim.disconnect()
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


def bench_decoder(rows):
    frames = []
    rng = np.random.default_rng(0)
    for _ in range(5000):
        data = struct.pack("<6hhBB", *rng.integers(-9000, 9000, 6), 2500, 0, 0)
        frames.append(encode_frame(bytes([20, 0xFF, 0x32, 0]) + data))
    stream = b"".join(frames)
    dec = FrameDecoder()
    t0 = time.perf_counter()
    n = 0
    for i in range(0, len(stream), 512):
        n += len(dec.feed(stream[i:i + 512]))
    dt = time.perf_counter() - t0
    rows.append(("Leptrino frame decoding", f"{n / dt:,.0f} frames/s",
                 f"{n / dt / 1200:.0f}x the sensor's 1200/s"))


def bench_pty_stream(rows):
    emu_mod = load_fake("leptrino_emulator")
    with emu_mod.LeptrinoEmulator() as emu:
        acq = LeptrinoAcquisition(LeptrinoSensor(emu.port))
        acq.connect()
        acq.configure(1200.0)
        acq.start(None, triggered=False)
        got, lost, t0 = 0, 0, time.monotonic()
        gaps = []
        last = time.monotonic()
        while time.monotonic() - t0 < 2.0:
            c = acq.read(0.05)
            if c is not None:
                got += c.n
                lost += int(c.flags.overrun)
                now = time.monotonic()
                gaps.append(now - last)
                last = now
        dt = time.monotonic() - t0
        acq.close()
        rows.append(("Leptrino driver over a real pty (emulator)", f"{got / dt:.0f} records/s",
                     f"{lost} chunks with lost records; median read gap "
                     f"{statistics.median(gaps) * 1e3:.1f} ms"))


def bench_measured_rate(rows, true_Hz=1000.0, repeats=5):
    emu_mod = load_fake("leptrino_emulator")
    errors = []
    with emu_mod.LeptrinoEmulator(rate_Hz=true_Hz) as emu:
        acq = LeptrinoAcquisition(LeptrinoSensor(emu.port))
        acq.connect()
        for _ in range(repeats):
            errors.append(abs(acq.measure_rate() / true_Hz - 1))
        acq.close()
    worst = max(errors)
    assumed = abs(1200.0 / true_Hz - 1)
    rows.append(("Leptrino record rate measured (1 s, 1000 Hz emulator)",
                 f"worst error {worst * 100:.2f} % of {repeats}",
                 f"{assumed / max(worst, 1e-9):.0f}x smaller than the assumed 1200 Hz's "
                 f"{assumed * 100:.0f} %; target 1 %: {'met' if worst <= 0.01 else 'missed'}"))


def bench_check_assembly(rows):
    import shutil
    import subprocess
    dll = Path(os.environ.get("NMSID_MCSUSBNET_DLL") or (
        ROOT.parent / "shared" / "vendor" / "McsUsbNet-5.3.15" / "McsUsbNet.dll"))
    if shutil.which("mono") is None or not dll.is_file():
        rows.append(("probe --check-assembly (real 5.3.15)", "not run",
                     "needs mono and the vendor assembly"))
        return
    from nmsid.drivers.mcs_surface import check_assembly
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import nmsid.drivers.mcs_surface"], check=True)
    base = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = check_assembly(dll)
    dt = time.perf_counter() - t0
    rows.append(("probe --check-assembly (real 5.3.15, mono)",
                 f"{dt:.2f} s, {result.n_checked - len(result.problems)}/{result.n_checked} "
                 "found", f"{dt / base:.1f}x a bare interpreter importing nmsid ({base:.2f} s)"))


def main() -> None:
    rows: list[tuple[str, str, str]] = []
    bench_render(rows)
    bench_decoder(rows)
    bench_pty_stream(rows)
    bench_measured_rate(rows)
    bench_check_assembly(rows)
    w = max(len(r[0]) for r in rows)
    v = max(len(r[1]) for r in rows)
    print(f"{'figure':<{w}}  {'value':<{v}}  note")
    for name, value, note in rows:
        print(f"{name:<{w}}  {value:<{v}}  {note}")


if __name__ == "__main__":
    main()
