"""Speed of the simulated rig (sim_backends), measured on this machine.

Prints one table: the participant simulation alone, one trial through the simulated
devices on the fast clock, a whole device-level session (both calibration ramps + 45
trials, without the engine), the cost of undoing simulated-ahead samples after a stop, and
in real time how long ``stop_now`` takes while the acquisition thread simulates.

    python bench/run.py sim_backends
"""

from __future__ import annotations

import threading
import time

import numpy as np


def _pct(a, q):
    return float(np.percentile(np.asarray(a), q))


def _best_of(fn, n=5):
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times))


def main() -> None:
    from nmsid.sim_backends import make_sim_rig
    from nmsid.sim_backends.direct_drive import (
        chirp_rE,
        currents_for,
        ramp_thresholds,
        run_waveform,
        waveform,
    )
    from nmsid.sim_backends.effects import (
        ActivationDynamics,
        BaselineDrift,
        DeadTime,
        Fatigue,
        FlexorExtensorAsymmetry,
        RecruitmentNonlinearity,
    )
    from nmsid.sim_backends.participant import default_participant
    from nmsid.sim_backends.simulation import ParticipantSimulator

    rows = []
    p = default_participant()
    p_all = p.with_effects(DeadTime(0.03), ActivationDynamics(0.02), Fatigue("linear", 20.0),
                           RecruitmentNonlinearity("power", gamma=1.5),
                           FlexorExtensorAsymmetry(1.2, 0.9), BaselineDrift(0.05, 0.2))
    rE = chirp_rE()
    I_e, I_f = currents_for(p.calibration, 0.6, rE)

    for name, q in (("nominal", p), ("all six effects", p_all)):
        sim = ParticipantSimulator(q)
        best, med = _best_of(lambda sim=sim: sim.simulate(I_e, I_f))
        rows.append((f"participant only, 15 s trial, one block ({name})", f"{best * 1e3:.1f} ms",
                     f"median {med * 1e3:.1f} ms"))

    rig = make_sim_rig(p, connect=True)
    wf = waveform(I_e, I_f)
    run_waveform(rig, wf)
    reads = []

    def one():
        _, chunks = run_waveform(rig, wf)
        reads.append(len(chunks))
    best, med = _best_of(one)
    rows.append(("15 s trial through the devices, fast clock (0.1 s chunks)",
                 f"{best * 1e3:.1f} ms", f"median {med * 1e3:.1f} ms, {reads[-1]} reads, "
                 f"{best / reads[-1] * 1e6:.0f} us/read"))

    def session():
        r = make_sim_rig(p, connect=True)
        ramp_thresholds(r, "ext")
        ramp_thresholds(r, "flex")
        levels = np.round(np.arange(0.30, 1.001, 0.05), 2)
        for _ in range(3):
            for sE in levels:
                run_waveform(r, waveform(*currents_for(p.calibration, sE, rE)))
        return r
    t0 = time.perf_counter()
    r = session()
    dt = time.perf_counter() - t0
    rows.append(("device-level session: 2 ramps + 45 trials (no engine)", f"{dt:.2f} s",
                 f"{r.world.n_runs} stimulator runs, {r.clock.monotonic_s():.0f} s virtual"))

    # undoing simulated-ahead samples: stop 7.5 s into a trial, then read on
    costs = []
    for _ in range(5):
        rr = make_sim_rig(p, connect=True)

        def stop_midway(rig_, chunk):
            if chunk is not None and chunk.start_index == 15000 - 200:
                rig_.stimulator.stop_now()
                t_a = time.perf_counter()
                rig_.acquisition.read(0.05)
                costs.append(time.perf_counter() - t_a)
                return True
            return False
        run_waveform(rr, wf, on_chunk=stop_midway)
    rows.append(("first read after stop_now mid-trial (rollback + re-simulate)",
                 f"{min(costs) * 1e3:.1f} ms", f"median {np.median(costs) * 1e3:.1f} ms"))

    # real time: stop_now duration while the acquisition thread reads
    lat = []
    rt = make_sim_rig(p, realtime=True, connect=True)
    short = waveform(*currents_for(p.calibration, 0.6, np.full(int(0.25 * 2000), 0.8)))
    for k in range(40):
        done = threading.Event()

        def reader(done=done):
            run_waveform(rt, short)
            done.set()
        th = threading.Thread(target=reader)
        th.start()
        time.sleep(0.05 + 0.1 * (k % 10) / 10)
        t_a = time.perf_counter()
        rt.stimulator.stop_now()
        lat.append(time.perf_counter() - t_a)
        th.join()
    zero = list(rt.output_zero_events)
    rows.append(("real time: stop_now() call duration (40 trips, reader active)",
                 f"p50 {_pct(lat, 50) * 1e6:.0f} us", f"p99 {_pct(lat, 99) * 1e6:.0f} us, "
                 f"{len(zero)} output-zero records"))

    w = max(len(r[0]) for r in rows)
    print(f"{'measure'.ljust(w)}  {'value':>12}  notes")
    for name, value, note in rows:
        print(f"{name.ljust(w)}  {value:>12}  {note}")


if __name__ == "__main__":
    main()
