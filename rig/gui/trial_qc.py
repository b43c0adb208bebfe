"""The quality control of each completed trial, in a worker thread.

Judging a trial (``analysis.qc.assess_level`` on its level's trials so far) takes from
0.1 s to over a second; done in the GUI thread it held the display back behind the engine
by tens of seconds on the fast clock (issue 39). Here it runs in one worker thread; the
verdicts come back through a queued signal. Jobs are coalesced per sE level: a job whose
level got a newer trial before it started is skipped (the newer job judges all of them).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor

from PySide6.QtCore import QObject, Qt, Signal

log = logging.getLogger(__name__)


class _Relay(QObject):
    done = Signal(int, object)      # session token, {schedule index: (decision, reasons)}


class TrialQC(QObject):
    """Judges completed trials in a worker; ``on_verdicts(verdicts)`` runs in the GUI
    thread with ``{schedule index: (decision, reasons)}`` for one level.

    Parameters
    ----------
    judge : callable
        ``judge({schedule index: Trial}) -> {schedule index: (decision, reasons)}``.
    on_verdicts : callable
        Called in the GUI thread with each level's verdicts.
    executor : concurrent.futures.Executor, optional
        Where the jobs run (the window passes the identification's one-thread pool: one
        analysis thread competes with the engine and the GUI for the GIL, not two);
        default: a one-thread pool of its own.
    """

    def __init__(self, judge: Callable[[dict], dict], on_verdicts: Callable[[dict], None],
                 executor: Executor | None = None, parent: QObject | None = None):
        super().__init__(parent)
        self.judge = judge
        self._on_verdicts = on_verdicts
        self._lock = threading.Lock()
        self._levels: dict[float, dict] = {}
        """sE -> {schedule index: the latest completed trial} (GUI thread writes)."""
        self._generation: dict[float, int] = {}
        self._token = 0
        self.pending = 0
        """Jobs submitted and not finished (tests wait for 0)."""
        self._own_pool = executor is None
        self._pool = executor if executor is not None else \
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="nmsid-qc")
        self._relay = _Relay()
        self._relay.done.connect(self._done, Qt.ConnectionType.QueuedConnection)

    def reset(self) -> None:
        """A new session: forget the trials; late verdicts of the last one are dropped."""
        with self._lock:
            self._token += 1
            self._levels, self._generation = {}, {}

    def submit(self, index: int, trial) -> None:
        """Judge ``trial`` (completed, schedule ``index``) with its level's trials."""
        if getattr(trial, "force_N", None) is None:
            return
        key = round(float(trial.sE), 9)
        with self._lock:
            level = self._levels.setdefault(key, {})
            level[int(index)] = trial
            gen = self._generation[key] = self._generation.get(key, 0) + 1
            job = (self._token, key, gen, dict(level))
        self.pending += 1
        try:
            self._pool.submit(self._work, *job)
        except RuntimeError:  # the window is closing
            self.pending -= 1

    def _work(self, token: int, key: float, gen: int, trials: dict) -> None:
        with self._lock:
            stale = token != self._token or self._generation.get(key) != gen
        verdicts: dict = {}
        if not stale:
            try:
                verdicts = self.judge(trials)
            except (ValueError, ArithmeticError) as exc:
                log.warning("quality control of sE %g failed: %s", key, exc)
            except Exception:  # never into Qt; the trial is in the file regardless
                log.exception("quality control of sE %g failed", key)
        self._relay.done.emit(token, verdicts)

    def _done(self, token: int, verdicts: dict) -> None:
        self.pending -= 1
        if token == self._token and verdicts:
            self._on_verdicts(verdicts)

    def shutdown(self, wait: bool = False) -> None:
        if self._own_pool:
            self._pool.shutdown(wait=wait, cancel_futures=True)
