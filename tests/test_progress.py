"""nmsid.progress: a tqdm bar on a terminal, plain lines into files and pipes (issue 39)."""

from __future__ import annotations

import io

from nmsid.progress import Progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_plain_lines_into_a_file_no_carriage_returns():
    out = io.StringIO()
    with Progress(4, "validating", unit="session", stream=out, every_s=0.0) as bar:
        for _ in range(4):
            bar.update()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0] == "validating: 0/4 session"
    assert lines[-1].startswith("validating: 4/4 session (")
    assert len(lines) == 5  # start, 1/4 .. 3/4 (every_s 0), the end
    assert repr(bar) == "Progress('validating', 4/4 session)"


def test_a_terminal_gets_a_bar_that_redraws_in_place():
    out = _Terminal()
    with Progress(3, "searching", unit="candidate", stream=out) as bar:
        for _ in range(3):
            bar.update()
    text = out.getvalue()
    assert text.startswith("\rsearching:") and "0/3" in text   # tqdm's bar
    assert "searching: 0/3" not in text and "\n" not in text  # no plain lines
    assert text.endswith("\r")  # erased at the end (leave=False): results follow cleanly
