"""Windows console control events: from the event to the stimulator's ``stop_now``.

A real-time simulated rig runs a long schedule of short trials in an engine thread, the
main thread waits as ``nmsid run``'s does (0.1 s joins) inside ``SessionSignals``, and
``on_signal`` zeroes the output (``engine.commands.estop(reason)``; an operator re-arms after each
trip). While a trial stimulates, another thread sends an event at a random moment
(10-130 ms into the trial: any phase of the 0.1 s chunks; 20-300 ms before, idle waits)
and records ``perf_counter()`` just before; the simulated stimulator records every
``stop_now`` call (``SimRig.world.stop_calls``): the latency is from the event to the
first one after it (an event that lands just after a trial's natural end meets the next
trial's, which is counted as it comes). Sources, like for like:

* ``CTRL_C_EVENT`` / ``CTRL_CLOSE_EVENT`` through ``FakeKernel32`` (the routine on the
  system's own thread): with ``stop_output`` (``nmsid run``: ``engine.commands.estop`` on that
  thread), and without it (the GUI: handed to the main thread by
  ``_thread.interrupt_main``, which runs it at its next 0.1 s turn); the Windows path,
  emulated on Linux (nmsid.testing.fake_windows_api);
* ``SIGINT`` sent with ``os.kill`` to this process: the POSIX path, the baseline.

No Windows machine measured this: on Windows the hand-over to the main thread is the same
Python call, but the wake-up of a waiting main thread may differ.

    python bench/bench_console_events.py        # 40 events per source
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.protocols import os_platform  # noqa: E402
from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.rig.engine import Engine, EngineObserver  # noqa: E402
from nmsid.rig.session_signals import SessionSignals  # noqa: E402
from nmsid.rig.states import State  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402
from nmsid.testing.fake_windows_api import (  # noqa: E402
    CTRL_C_EVENT,
    CTRL_CLOSE_EVENT,
    FakeKernel32,
    FakeMsvcrt,
)


def _measure(n: int, source: str, seed: int = 1) -> np.ndarray:
    rig = make_sim_rig(seed=seed, realtime=True)
    cfg = config_from_dict({
        "participant": "BENCH", "seed": seed,
        "protocol": {"sE_levels": [round(0.3 + 0.05 * k, 2) for k in range(15)],
                     "repeats": int(np.ceil((2 * n + 5) / 15)), "steady_s": 0.0,
                     "chirp_s": 0.5, "rest_s": 0.0},
        "calibration": {"manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                                   "Ifmax_mA": 8.0}}})
    stimulating = threading.Event()
    rng = np.random.default_rng(seed)
    sent: list[float] = []
    k32 = FakeKernel32(close_timeout_s=0.0)  # no process to end here: record only

    class Operator(EngineObserver):
        def on_state(self, old, new, reason):
            if new is State.STIMULATING:
                stimulating.set()
            elif new is State.TRIPPED:
                eng.commands.rearm()

    tmp = tempfile.mkdtemp(prefix="nmsid-bench-console-")
    windows = source != "SIGINT"  # "... now": stop_output on the routine's thread
    with os_platform.forced("windows" if windows else "posix"), \
            os_platform.fake_windows_api(kernel32=k32, msvcrt=FakeMsvcrt()):
        eng = Engine(cfg, rig, Path(tmp) / "console.h5", observer=Operator())

        def sender():
            while len(sent) < n:
                if not stimulating.wait(1.0):
                    if eng.state is State.PAUSED:   # schedule done, aborted trials left
                        break
                    continue
                stimulating.clear()
                time.sleep(rng.uniform(0.01, 0.13))  # any phase of a 0.1 s chunk
                if eng.state is not State.STIMULATING:
                    continue
                sent.append(time.perf_counter())
                if source == "SIGINT":
                    os.kill(os.getpid(), signal.SIGINT)
                else:
                    k32.deliver(CTRL_C_EVENT if source.startswith("CTRL_C_EVENT") else
                                CTRL_CLOSE_EVENT)
            eng.commands.abort("bench done")

        worker = threading.Thread(target=eng.run, daemon=True)
        stop_output = eng.commands.estop if source.endswith("now") else None
        with SessionSignals(lambda signum, reason: eng.commands.estop(reason), stop_output):
            worker.start()
            threading.Thread(target=sender, daemon=True).start()
            while worker.is_alive():  # as nmsid run: short joins
                worker.join(0.1)
    rig.close()
    zeros = sorted(perf for _, perf in rig.world.stop_calls)
    lat = [min((z for z in zeros if z >= t), default=np.nan) - t for t in sent]
    return np.asarray([x for x in lat if np.isfinite(x)]) * 1000.0


def main(n: int = 40) -> None:
    logging.disable(logging.WARNING)
    print(f"console event -> stimulator stop_now, real-time simulated rig, {n} events "
          "each; main thread waiting in 0.1 s joins as nmsid run's")
    print(f"{'source':44s} {'n':>4s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} "
          f"{'p50 / SIGINT':>13s}")
    base = None
    for source, label in (
            ("SIGINT", "SIGINT (os.kill; POSIX path, baseline)"),
            ("CTRL_C_EVENT now", "CTRL_C_EVENT, stop_output (nmsid run)"),
            ("CTRL_CLOSE_EVENT now", "CTRL_CLOSE_EVENT, stop_output (nmsid run)"),
            ("CTRL_C_EVENT", "CTRL_C_EVENT, main thread only (GUI)"),
            ("CTRL_CLOSE_EVENT", "CTRL_CLOSE_EVENT, main thread only (GUI)")):
        lat = _measure(n, source)
        p50, p99, mx = (np.percentile(lat, 50), np.percentile(lat, 99), lat.max()) \
            if lat.size else (float("nan"),) * 3
        base = p50 if base is None else base
        print(f"{label:44s} {lat.size:4d} {p50:8.2f} {p99:8.2f} {mx:8.2f} "
              f"{p50 / base:13.1f}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40)
