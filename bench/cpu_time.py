"""CPU time of a call, for the benchmarks that time one stage in process."""

from __future__ import annotations

import statistics
import time
from typing import Callable


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
