"""Progress of long work (issue 39): what a command is doing and how far it is.

One helper for every command whose work can take more than a few seconds (``design``,
``identify``, ``study``, ...). On a terminal it draws a tqdm bar on stderr; into a file or a
pipe it writes plain lines instead (no carriage returns, no escape codes), at the start, at
most every ``every_s`` seconds and at the end, so a log stays readable. Results go to
stdout as before: progress never mixes into what a script parses.

Examples
--------
>>> import io
>>> out = io.StringIO()
>>> with Progress(3, "validating", unit="participant", stream=out) as bar:
...     for _ in range(3):
...         bar.update()
>>> print(out.getvalue().splitlines()[0])
validating: 0/3 participant
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from tqdm import tqdm


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # closed, or not a real stream
        return False


def say(text: str, stream: TextIO | None = None) -> None:
    """One line of what the command is doing now (stderr by default)."""
    out = stream if stream is not None else sys.stderr
    print(text, file=out, flush=True)


class Progress:
    """A count towards ``total``: a tqdm bar on a terminal, plain lines elsewhere.

    Parameters
    ----------
    total : int
        Steps the work has.
    desc : str
        What is being done ("searching 240 candidates").
    unit : str
        What one step is, for the plain lines and the bar.
    stream : text stream, optional
        Where to write (default stderr).
    every_s : float
        Plain lines: at most one every this many seconds (besides the first and the last).
    """

    def __init__(self, total: int, desc: str, *, unit: str = "step",
                 stream: TextIO | None = None, every_s: float = 5.0):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._every_s = float(every_s)
        self._t0 = self._last = time.monotonic()
        self._bar = None
        if _is_terminal(self._stream):
            self._bar = tqdm(total=self.total, desc=desc, unit=f" {unit}",
                             file=self._stream, leave=False, dynamic_ncols=True)
        else:
            say(f"{desc}: 0/{self.total} {unit}", self._stream)

    def update(self, n: int = 1) -> None:
        """``n`` more steps done."""
        self.done += n
        if self._bar is not None:
            self._bar.update(n)
            return
        now = time.monotonic()
        if now - self._last >= self._every_s and self.done < self.total:
            self._last = now
            say(f"{self.desc}: {self.done}/{self.total} {self.unit} "
                f"({now - self._t0:.0f} s)", self._stream)

    def close(self) -> None:
        """End the bar (terminal) or write the last line (elsewhere)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self.done:
            say(f"{self.desc}: {self.done}/{self.total} {self.unit} "
                f"({time.monotonic() - self._t0:.0f} s)", self._stream)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Progress({self.desc!r}, {self.done}/{self.total} {self.unit})"
