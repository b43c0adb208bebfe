"""LSL marker timing: the ``trial_start`` marker against the stimulator's start it marks.

A real-time simulated rig runs a short schedule with ``--lsl``'s observer
(:class:`nmsid.rig.lsl.LslObserver`); the simulated stimulator's ``start()`` is wrapped to
record ``pylsl.local_clock()`` at the call (the truth: the acquisition's sample 0 is the
stimulator's start); an independent inlet reads the markers. The error per trial is the
marker's time stamp minus that start, in ms: the observer estimates each trial's onset at its
first chunk as arrival time minus the samples it holds, so the error is the chunk's delivery
latency (and the acquisition's start latency), not LSL's transport.

LSL stays on this machine (``LSLAPICFG``: ResolveScope = machine, IPv6 off).

    python bench/bench_lsl.py            # 8 trials, ~25 s
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.rig.lsl import LslObserver, machine_only_config  # noqa: E402

TMP = Path(tempfile.mkdtemp(prefix="nmsid-bench-lsl-"))
machine_only_config(TMP)                     # before pylsl is first used

import pylsl  # noqa: E402

from nmsid.protocols.config import config_from_dict  # noqa: E402
from nmsid.rig.engine import Engine  # noqa: E402
from nmsid.sim_backends import make_sim_rig  # noqa: E402


def main() -> int:
    rig = make_sim_rig(seed=2, realtime=True)
    starts: list[float] = []
    original = rig.stimulator.start

    def start():
        starts.append(pylsl.local_clock())
        original()
    rig.stimulator.start = start
    cfg = config_from_dict({
        "participant": "BENCHLSL", "seed": 2,
        "protocol": {"sE_levels": [0.4, 0.6, 0.8, 0.5], "repeats": 2, "steady_s": 0.5,
                     "chirp_s": 1.0, "rest_s": 0.0},
        "calibration": {"manual": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
                                   "Ifmax_mA": 8.0}}})
    obs = LslObserver(None, cfg.protocol.fs_Hz, name="nmsidbench", participant="BENCHLSL")
    found = pylsl.resolve_byprop("source_id", "nmsidbench-BENCHLSL-markers", 1, 10.0)
    inlet = pylsl.StreamInlet(found[0], max_buflen=120)
    inlet.open_stream(10.0)
    summary = Engine(cfg, rig, TMP / "lsl.h5", observer=obs).run()
    del obs                                  # outlets closed: the inlet drains, then ends
    marks: list[tuple[float, dict]] = []
    while True:
        chunk, ts = inlet.pull_chunk(timeout=0.5)
        if not chunk:
            break
        marks += [(t, json.loads(c[0])) for c, t in zip(chunk, ts, strict=True)]
    stamps = [t for t, m in marks if m["event"] == "trial_start"]
    n = min(len(stamps), len(starts))
    err_ms = (np.asarray(stamps[:n]) - np.asarray(starts[:n])) * 1e3
    print(f"{summary.n_completed} trials; chunks of 20 ms (make_sim_rig in real time) at "
          f"{cfg.protocol.fs_Hz:g} Hz")
    print(f"trial_start marker - stimulator start: median {np.median(err_ms):+.2f} ms, "
          f"min {err_ms.min():+.2f} ms, max {err_ms.max():+.2f} ms, "
          f"max |error| {np.abs(err_ms).max():.2f} ms over {n} trials")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
