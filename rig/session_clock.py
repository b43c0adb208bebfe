"""Session time that never steps: monotonic offsets from a recorded UTC start.

Trial and event times of a session file are written as ISO 8601 UTC strings. Taken from
the wall clock, they go backwards or jump by an hour when the computer's clock is set
(NTP, a daylight-saving mistake, an operator). :class:`SessionClock` reads the wall clock
once, when the writer opens the session, and from then on adds the elapsed time of
``time.perf_counter``, which never steps. Each time it is read it also compares the two;
a difference that changes by more than :data:`STEP_THRESHOLD_S` is a step of the wall
clock, which the caller records as a ``clock_step`` event (the file's times stay on the
monotonic line).

Why ``perf_counter`` and not ``time.monotonic``: on Windows, Python 3.11 and 3.12 read
``time.monotonic`` from ``GetTickCount64``, whose resolution is the 15.6 ms system timer
tick (Python docs, ``time.get_clock_info``; Microsoft, "GetTickCount64"), while
``perf_counter`` reads ``QueryPerformanceCounter`` (sub-microsecond; Microsoft,
"Acquiring high-resolution time stamps": it does not step with the system time). On
Linux both are ``CLOCK_MONOTONIC``.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable

STEP_THRESHOLD_S = 1.0
"""A change of (wall - monotonic) larger than this is reported as a wall-clock step
(smaller ones are NTP's slewing and scheduling jitter)."""


def format_utc_ms(t: _dt.datetime) -> str:
    """ISO 8601 UTC with milliseconds and a ``Z`` suffix."""
    return t.astimezone(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


class SessionClock:
    """UTC times as monotonic offsets from the wall-clock time read at construction.

    Parameters
    ----------
    wall : callable, optional
        Seconds since the epoch (default ``time.time``; tests pass a fake).
    mono : callable, optional
        A clock that never steps, in seconds (default ``time.perf_counter``).
    """

    def __init__(self, wall: Callable[[], float] = time.time,
                 mono: Callable[[], float] = time.perf_counter):
        self._wall, self._mono = wall, mono
        self.start_wall_s = wall()
        self.start_mono_s = mono()
        self.start_utc = format_utc_ms(_dt.datetime.fromtimestamp(self.start_wall_s,
                                                                  _dt.UTC))
        self._offset_s = 0.0  # (wall - monotonic) - at the start, as last reported

    def elapsed_s(self) -> float:
        """Seconds since the start, on the monotonic clock."""
        return self._mono() - self.start_mono_s

    def utc(self) -> str:
        """The current time: the recorded start plus the monotonic elapsed time."""
        t = self.start_wall_s + self.elapsed_s()
        return format_utc_ms(_dt.datetime.fromtimestamp(t, _dt.UTC))

    def step(self) -> str:
        """If the wall clock stepped since the last call (or the start), the event detail
        describing it; else an empty string."""
        offset = (self._wall() - self.start_wall_s) - self.elapsed_s()
        delta = offset - self._offset_s
        if abs(delta) <= STEP_THRESHOLD_S:
            return ""
        self._offset_s = offset
        wall_now = format_utc_ms(_dt.datetime.fromtimestamp(self._wall(), _dt.UTC))
        return (f"the computer's clock stepped by {delta:+.3f} s (it reads {wall_now}); "
                f"the file's times keep following the monotonic clock from "
                f"{self.start_utc} (now {self.utc()})")
