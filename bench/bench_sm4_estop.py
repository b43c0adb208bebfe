"""ScienceMode4 (P24, RehaMove3) on the byte-level fake: the stop to the last pulse.

Each run starts a 40 Hz trial (25 ms period) on the fake, calls ``stop_now()`` at a varied
moment and measures, on the fake's clock, the last low-level pulse's start (or, in mid
level, the end of the device's pulse train, ended by the confirmed Ml_stop) minus the
moment of the stop. Negative: the last pulse began before the stop. The fake runs on the
host's clock (no speed-up), so the figure includes the driver's own thread latency.

    python bench/bench_sm4_estop.py          # 10 stops per device and mode, ~15 s
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from nmsid.drivers.interfaces import CheckedWaveform  # noqa: E402
from nmsid.drivers.sciencemode4 import P24, REHAMOVE3, Sm4Stimulator  # noqa: E402
from nmsid.drivers.sciencemode4_mid import Sm4MidLevelStimulator  # noqa: E402
from nmsid.testing.fakes.fake_sciencemode4 import FakeSm4  # noqa: E402


def main(n: int = 10) -> int:
    for label, cls in (("low", Sm4Stimulator), ("mid", Sm4MidLevelStimulator)):
        for model in (P24, REHAMOVE3):
            ms = []
            for k in range(n):
                fake = FakeSm4(model.title.split()[-1])
                stim = cls("COM9", model, ceiling_ext_mA=20.0, ceiling_flex_mA=20.0,
                           pulse_rate_Hz=40.0, open_port=fake.open, clock=fake.clock)
                stim.connect()
                env = np.full(2000, 10.0)
                stim.load(CheckedWaveform(env, env / 2, 1000.0, 40.0, 20.0, 20.0))
                stim.arm()
                stim.start()
                time.sleep(0.1 + 0.023 * k)
                t = fake.clock()
                stim.stop_now()
                last = (max(p[0] for p in fake.pulses) if label == "low"
                        else fake.ml_spans[-1][1])
                ms.append((last - t) * 1e3)
                stim.disconnect()
            print(f"{label} level, {model.title}: stop -> last pulse median "
                  f"{np.median(ms):+.2f} ms, max {max(ms):+.2f} ms over {n} stops "
                  "(period 25 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
