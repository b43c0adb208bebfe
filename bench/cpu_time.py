"""CPU time of a call and the machine's load, for the benchmarks that time one stage in
process."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable


def cpu_median(fn: Callable[[], object], runs: int) -> float:
    """Median CPU seconds (``time.process_time``: this process, every thread) of ``fn()``
    over ``runs`` calls, after one warm-up call (caches, first-call imports)."""
    fn()
    times = []
    for _ in range(max(1, runs)):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)


def load_1min() -> str:
    """The 1-minute load average as printed by the benchmarks, or "n/a" (Windows has
    none: ``os.getloadavg`` does not exist there)."""
    getloadavg = getattr(os, "getloadavg", None)
    return f"{getloadavg()[0]:.2f}" if getloadavg else "n/a"
