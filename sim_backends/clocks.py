"""Clocks of the simulated rig: virtual (as fast as possible) and real time.

The engine only calls ``monotonic_s()`` and ``sleep()`` (``drivers.interfaces.Clock``), so
its code is the same for both. On the :class:`FastClock` time is virtual: ``sleep``
advances it at once, and the simulated acquisition advances it by each chunk's duration
when it hands the chunk over. On the :class:`SimRealClock` time is ``time.monotonic`` and
the acquisition blocks until a chunk's last sample is due.
"""

from __future__ import annotations

import threading
import time

from nmsid.drivers.interfaces import RealClock


class FastClock:
    """Virtual time, starting at ``start_s``: ``sleep`` advances it without waiting.

    Thread-safe: several threads may read it; ``sleep`` / ``advance_to`` only move it
    forward.

    Examples
    --------
    >>> c = FastClock()
    >>> c.sleep(2.5); c.monotonic_s()
    2.5
    """

    realtime = False

    def __init__(self, start_s: float = 0.0):
        self._t = float(start_s)
        self._lock = threading.Lock()

    def monotonic_s(self) -> float:
        return self._t

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            with self._lock:
                self._t += float(duration_s)
        else:
            time.sleep(0)  # let other threads (GUI, E-stop watcher) run

    def advance_to(self, t_s: float) -> None:
        """Move time forward to ``t_s`` (no-op if already later)."""
        with self._lock:
            if t_s > self._t:
                self._t = float(t_s)


class SimRealClock(RealClock):
    """Wall-clock time (``time.monotonic``), as the hardware rig uses."""

    realtime = True

    def advance_to(self, t_s: float) -> None:
        """Block until ``t_s`` (for symmetry with :class:`FastClock`)."""
        dt = t_s - self.monotonic_s()
        if dt > 0:
            time.sleep(dt)


__all__ = ["FastClock", "SimRealClock"]
