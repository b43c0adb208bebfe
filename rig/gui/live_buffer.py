"""A thread-safe rolling buffer of the current trial's signals, for the live plots.

The engine thread appends each acquisition chunk (:meth:`LiveBuffer.append`: a copy into
preallocated arrays under a lock, no allocation, no Qt); the GUI thread takes a snapshot
at its redraw rate (:meth:`LiveBuffer.snapshot`). Neither side waits for the other for
longer than one array copy, so drawing never delays acquisition or the interlock.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

#: The signals kept per sample, in this order.
SIGNALS = ("force_N", "rE", "I_ext_mA", "I_flex_mA")


@dataclass(frozen=True)
class LiveSnapshot:
    """A copy of the buffered window, oldest sample first.

    Attributes
    ----------
    trial_index : int
        Schedule index of the trial the samples belong to (-1: none yet).
    t_s : numpy.ndarray
        Sample times in s after stimulation onset.
    force_N, rE, I_ext_mA, I_flex_mA : numpy.ndarray
        The signals at those times.
    generation : int
        Increases with every append or reset; equal generations mean equal data.
    """

    trial_index: int
    t_s: np.ndarray
    force_N: np.ndarray
    rE: np.ndarray
    I_ext_mA: np.ndarray
    I_flex_mA: np.ndarray
    generation: int
    target_N: np.ndarray | None = None
    """A tracking trial's target force at those times (NaN where none was given; None:
    no target in the window)."""

    @property
    def n(self) -> int:
        return len(self.t_s)


class LiveBuffer:
    """Rolling window of the last ``window_s`` seconds of the trial being run.

    Parameters
    ----------
    window_s : float
        Length of the window kept, s (> 0).
    fs_Hz : float
        Sample rate of the acquisition, Hz (> 0).

    Examples
    --------
    >>> import numpy as np
    >>> buf = LiveBuffer(window_s=1.0, fs_Hz=10.0)
    >>> buf.start_trial(0)
    >>> buf.append(0, 0, np.arange(15.0), np.zeros(15), np.zeros(15), np.zeros(15))
    >>> snap = buf.snapshot()
    >>> snap.n, float(snap.force_N[0]), float(snap.t_s[-1])
    (10, 5.0, 1.4)
    """

    def __init__(self, window_s: float = 10.0, fs_Hz: float = 2000.0):
        if not (np.isfinite(window_s) and window_s > 0):
            raise ValueError(f"live plot window_s must be > 0 s, got {window_s!r}")
        if not (np.isfinite(fs_Hz) and fs_Hz > 0):
            raise ValueError(f"live plot fs_Hz must be > 0 Hz, got {fs_Hz!r}")
        self._lock = threading.Lock()
        self.fs_Hz = float(fs_Hz)
        self.capacity = max(1, int(round(window_s * fs_Hz)))
        self._data = np.zeros((len(SIGNALS), self.capacity))
        self._index = np.zeros(self.capacity, dtype=np.int64)
        self._target = np.full(self.capacity, np.nan)
        self._has_target = False
        self._last_chunk: tuple[int, int, int, int] | None = None
        """(trial, start index, ring position, samples) of the last chunk appended."""
        self._n_total = 0          # samples written since the trial started
        self._trial_index = -1
        self._generation = 0
        self.n_chunks = 0
        """Chunks appended since construction (all trials)."""

    def start_trial(self, trial_index: int) -> None:
        """Forget the previous trial's samples; the next chunks belong to ``trial_index``."""
        with self._lock:
            self._n_total = 0
            self._trial_index = int(trial_index)
            self._has_target = False
            self._generation += 1

    def append(self, trial_index: int, start_index: int, force_N, rE, I_ext_mA,
               I_flex_mA) -> None:
        """Add one chunk (called from the engine thread; never blocks for long).

        Parameters
        ----------
        trial_index : int
            Schedule index of the trial the chunk belongs to; a chunk of another trial
            than the current one starts a new window.
        start_index : int
            Index of the chunk's first sample since stimulation onset.
        force_N, rE, I_ext_mA, I_flex_mA : array_like
            The chunk's samples (same length).
        """
        arrays = [np.asarray(a, dtype=np.float64).reshape(-1)
                  for a in (force_N, rE, I_ext_mA, I_flex_mA)]
        n = len(arrays[0])
        if any(len(a) != n for a in arrays):
            raise ValueError("live buffer chunk arrays differ in length: "
                             + ", ".join(f"{s}={len(a)}"
                                         for s, a in zip(SIGNALS, arrays, strict=True)))
        if n == 0:
            return
        idx = np.arange(start_index, start_index + n, dtype=np.int64)
        if n > self.capacity:
            arrays = [a[-self.capacity:] for a in arrays]
            idx = idx[-self.capacity:]
            n = self.capacity
        with self._lock:
            if trial_index != self._trial_index:
                self._n_total = 0
                self._trial_index = int(trial_index)
                self._has_target = False
            pos = self._n_total % self.capacity
            first = min(n, self.capacity - pos)
            for row, a in enumerate(arrays):
                self._data[row, pos:pos + first] = a[:first]
                self._data[row, :n - first] = a[first:]
            self._index[pos:pos + first] = idx[:first]
            self._index[:n - first] = idx[first:]
            self._target[pos:pos + first] = np.nan
            self._target[:n - first] = np.nan
            self._last_chunk = (int(trial_index), int(idx[0]), pos, n)
            self._n_total += n
            self._generation += 1
            self.n_chunks += 1

    def set_target(self, trial_index: int, start_index: int, target_N) -> None:
        """The target force of the chunk just appended (a tracking trial; engine thread).

        Ignored unless it matches that chunk's trial and first sample.
        """
        target = np.asarray(target_N, dtype=np.float64).reshape(-1)
        with self._lock:
            last = self._last_chunk
            if last is None or last[0] != trial_index or trial_index != self._trial_index:
                return
            _trial, first_index, pos, n = last
            skip = first_index - int(start_index)   # the chunk kept only its last samples
            if skip < 0 or len(target) - skip < n:
                return
            target = target[skip:skip + n]
            first = min(n, self.capacity - pos)
            self._target[pos:pos + first] = target[:first]
            self._target[:n - first] = target[first:]
            self._has_target = True
            self._generation += 1

    @property
    def generation(self) -> int:
        return self._generation

    @property
    def trial_index(self) -> int:
        """Schedule index of the trial being buffered (-1: none)."""
        return self._trial_index

    @property
    def samples_in_trial(self) -> int:
        """Samples appended since that trial started (its elapsed time x ``fs_Hz``)."""
        return self._n_total

    def snapshot(self) -> LiveSnapshot:
        """A copy of the window (called from the GUI thread)."""
        with self._lock:
            n = min(self._n_total, self.capacity)
            pos = self._n_total % self.capacity
            if self._n_total <= self.capacity:
                data = self._data[:, :n].copy()
                idx = self._index[:n].copy()
                target = self._target[:n].copy()
            else:
                data = np.concatenate((self._data[:, pos:], self._data[:, :pos]), axis=1)
                idx = np.concatenate((self._index[pos:], self._index[:pos]))
                target = np.concatenate((self._target[pos:], self._target[:pos]))
            trial, gen, has_target = self._trial_index, self._generation, self._has_target
        return LiveSnapshot(trial, idx / self.fs_Hz, data[0], data[1], data[2], data[3],
                            generation=gen,
                            target_N=target if has_target else None)
