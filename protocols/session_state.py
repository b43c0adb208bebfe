"""Is a session finished, live or incomplete? What did an interrupted end leave behind?

A reader's view of a session's store (no lock taken, nothing changed): the published
file, its write-ahead journal ``<file>.journal/`` and the single-writer lock. Used by
``nmsid validate`` and ``nmsid study`` to tell a finished session from

* a **live** one: a process holds the writer lock now (the file is the version published
  so far; trials recorded since are in the journal until the session ends);
* an **incomplete** one: nobody writes it, but a journal beside it holds trials the file
  lacks (a killed or failed session not yet recovered: ``nmsid recover``);

and to list the **leftovers** of an interrupted clean end or of killed writers
(``<file>.journal.done-<pid>``, ``<file>.journal.tmp-<pid>``,
``<file>.journal.headerless-<time>``, ``<file>.writing-<pid>``, ``.recovering-<pid>``,
``*.tmp`` inside the journal), which the next command that writes the session removes
(:func:`nmsid.rig.recovery.remove_leftovers`).

This module sits in ``protocols`` (it reads only file names, the journal's entry names
and the lock) so that ``study`` may use it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from nmsid.protocols.session_lock import live_writer
from nmsid.protocols.session_model import TRIAL_NAME_PATTERN, _h5py

_TRIAL_ENTRY = re.compile(r"^trial-(\d{4,})\.npz$")
_LEFTOVER = re.compile(r"\.(writing-\d+|recovering-\d+|journal\.(done|tmp)-\d+"
                       r"|journal\.headerless-[0-9TZ-]+)$")


@dataclass
class SessionState:
    """The store's state of one session (see the module docstring)."""

    path: str
    live_writer: str = ""
    """Who writes the session now (empty: nobody)."""
    file_trials: int | None = None
    """Trials in the published file (None: missing or unreadable)."""
    journal_trials: int = 0
    """Trial entries in the journal (0: no journal)."""
    has_journal: bool = False
    leftovers: list[str] = field(default_factory=list)
    """Names of leftovers beside or inside the session (see the module docstring)."""

    @property
    def live(self) -> bool:
        return bool(self.live_writer)

    @property
    def incomplete(self) -> bool:
        """A journal holds more trials than the file, and nobody writes the session."""
        return not self.live and self.has_journal and \
            self.journal_trials > (self.file_trials or 0)

    @property
    def label(self) -> str:
        """``"live"``, ``"incomplete"`` or ``"finished"`` (a journal that adds nothing
        does not make a session incomplete)."""
        return "live" if self.live else "incomplete" if self.incomplete else "finished"

    def describe(self) -> str:
        """One clause for a report, empty for a finished session without leftovers."""
        parts = []
        if self.live:
            parts.append(f"live session: written now by {self.live_writer}; the file holds "
                         f"{self.file_trials or 0} trial(s) as published so far, the journal "
                         f"{self.journal_trials}")
        elif self.incomplete:
            parts.append(f"incomplete: the journal holds {self.journal_trials} trial(s), the "
                         f"file {self.file_trials or 0} (the session was killed or failed and "
                         f"not recovered): run `nmsid recover {self.path}`")
        if self.leftovers:
            parts.append(f"leftovers of an interrupted end: {', '.join(self.leftovers)} (the "
                         "next `nmsid recover` or `run --resume` of it removes them)")
        return "; ".join(parts)


def _count_file_trials(path: Path) -> int | None:
    try:
        with _h5py().File(path, "r") as f:
            return len([k for k in f["trials"] if TRIAL_NAME_PATTERN.match(k)])
    except (OSError, KeyError, ValueError, RuntimeError, TypeError):
        return None


def session_state(path: str | os.PathLike, *, count_file_trials: bool = True
                  ) -> SessionState:
    """The store's state of the session file ``path`` (changes nothing)."""
    path = Path(path)
    st = SessionState(str(path))
    writer = live_writer(path)
    if writer is not None and writer.pid != os.getpid():
        st.live_writer = writer.describe()
    if count_file_trials and path.is_file():
        st.file_trials = _count_file_trials(path)
    jdir = path.with_name(path.name + ".journal")
    if jdir.is_dir():
        st.has_journal = True
        try:
            names = os.listdir(jdir)
        except OSError:
            names = []
        st.journal_trials = sum(1 for n in names if _TRIAL_ENTRY.match(n))
        st.leftovers += [f"{jdir.name}/{n}" for n in sorted(names) if n.endswith(".tmp")]
    try:
        beside = sorted(os.listdir(path.parent))
    except OSError:
        beside = []
    st.leftovers += [n for n in beside
                     if n.startswith(path.name) and _LEFTOVER.fullmatch(n[len(path.name):])]
    if st.live:  # a live writer's temp files are its own, not leftovers
        st.leftovers = [n for n in st.leftovers if ".headerless-" in n]
    return st
