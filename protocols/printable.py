"""Text from files (participant codes, notes, reasons) shown without its control characters.

A session file's attributes are data: a participant attribute holding terminal escapes
(``"\\x1b]0;owned\\x07"``) or other control characters must never reach a terminal or an
HTML report raw. :func:`escape_controls` turns each such character into a visible escape
(``\\x1b``); the command line (``rig.cli``) passes everything it prints through it, and the
HTML reports pass their whole text through it.
"""

from __future__ import annotations

import re

#: C0 controls except tab, newline, carriage return; DEL; C1 controls; the Unicode
#: bidirectional overrides and isolates (which reorder what a reader sees).
_CONTROLS = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")


def _escape(m: re.Match) -> str:
    c = ord(m.group(0))
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def escape_controls(text: str) -> str:
    """``text`` with every control character (but tab, newline and carriage return)
    written as a visible escape.

    Examples
    --------
    >>> escape_controls("P01\\x1b[2J\\n")
    'P01\\\\x1b[2J\\n'
    """
    return _CONTROLS.sub(_escape, text)

