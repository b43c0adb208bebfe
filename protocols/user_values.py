"""Values a user types, bounded once for the command line and the GUI: seeds, session
file names (long enough for every name derived from them), non-UTF-8 names.

Standard library only: the command line's argument parsing imports it (``nmsid --help``
loads no numpy or h5py).
"""

from __future__ import annotations

import os

SEED_MAX = 2 ** 63 - 1
"""Seeds are stored as 64-bit signed integers in the session file (``seed``): [0, SEED_MAX]
in the CLI and the GUI alike; no seed means a random one, recorded."""

NAME_MAX_BYTES = 255
"""The longest file name (one path component) of NTFS (255 UTF-16 units), ext4, APFS and
XFS (255 bytes)."""
PID_DIGITS = 10
"""Digits of the largest process id a derived name may carry (Windows: a 32-bit DWORD,
4294967295; Linux: at most 4194304)."""
UTC_STAMP_CHARS = len("20261124T234000Z")
#: Every suffix the store, the journal and recovery add to a session file's name
#: (``rig/journal.py``, ``rig/session_log.py``, ``rig/recovery.py``,
#: ``protocols/session_publish.py``, ``protocols/session_lock.py``,
#: ``protocols/output_paths.py``), at its longest.
DERIVED_SUFFIXES = {
    "lock": len(".lock"),
    "publish temp": len(".writing-") + PID_DIGITS,
    "recovery temp": len(".recovering-") + PID_DIGITS,
    "journal": len(".journal"),
    "journal being built": len(".journal.tmp-") + PID_DIGITS,
    "journal removed at the end": len(".journal.done-") + PID_DIGITS,
    "damaged file kept aside": len(".damaged-") + UTC_STAMP_CHARS + len("-999"),
    "headerless journal kept aside": len(".journal.headerless-") + UTC_STAMP_CHARS
    + len("-999"),
    "output temp": len(".nmsid-tmp-") + len("-old-") + PID_DIGITS,
}
LONGEST_SUFFIX_BYTES = max(DERIVED_SUFFIXES.values())
MAX_SESSION_NAME_BYTES = NAME_MAX_BYTES - LONGEST_SUFFIX_BYTES
"""The longest session file name (UTF-8 bytes) whose every derived name still fits
:data:`NAME_MAX_BYTES` (215: the headerless journal's aside name adds 40)."""


def shown(text: str) -> str:
    """A path as printable text: bytes that are not UTF-8 (carried by ``sys.argv`` as
    surrogate escapes) shown as ``\\xNN``."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        return os.fsencode(text).decode("utf-8", "backslashreplace")


def non_utf8_problem(text: str) -> str | None:
    """One line if ``text`` (a path from the command line) holds bytes that are not
    UTF-8, else None: such a name cannot be stored in a session's reports, NWB files or
    configuration (UTF-8 by contract)."""
    if shown(text) == text:
        return None
    return (f"the name {shown(text)} holds bytes that are not UTF-8 (shown as \\xNN); "
            "rename it with a UTF-8 name (session files, reports and NWB exports store "
            "names as UTF-8)")


def name_length_problem(text: str) -> str | None:
    """One line if the file name (last component) of ``text`` is too long for the names
    the journal and recovery derive from it (:data:`MAX_SESSION_NAME_BYTES`), else None."""
    name = os.path.basename(os.path.normpath(text)) if text else ""
    try:
        size = len(name.encode("utf-8"))
    except UnicodeEncodeError:
        size = len(os.fsencode(name))
    if size <= MAX_SESSION_NAME_BYTES:
        return None
    return (f"the file name {shown(name)[:40]}... is {size} bytes long; at most "
            f"{MAX_SESSION_NAME_BYTES} bytes (UTF-8) are valid, so that the journal's and "
            f"recovery's names beside it (up to {LONGEST_SUFFIX_BYTES} bytes longer) fit the "
            f"file system's {NAME_MAX_BYTES}")


def parse_seed(text: str, *, empty_is_random: bool = False) -> tuple[int | None, str | None]:
    """``(seed, None)`` for a whole number in [0, :data:`SEED_MAX`], ``(None, None)`` for
    an empty text when ``empty_is_random`` (the GUI's empty field), else ``(None, one line
    saying what is valid)``."""
    text = text.strip()
    if not text and empty_is_random:
        return None, None
    try:
        value = int(text, 10)
    except ValueError:
        return None, (f"seed {text!r} is not a whole number; give a seed in [0, {SEED_MAX}]"
                      + (" or leave it empty for a random one" if empty_is_random else ""))
    if not 0 <= value <= SEED_MAX:
        return None, (f"seed {value} is outside [0, {SEED_MAX}] (seeds are stored as 64-bit "
                      "integers; no seed means a random one, recorded)")
    return value, None


def one_line(exc: BaseException | str) -> str:
    """An error as one line for a log or a panel: its message with newlines shown as
    `` | `` (never a traceback), or its type's name when it has no message."""
    text = str(exc).strip() or (type(exc).__name__ if isinstance(exc, BaseException) else "")
    return " | ".join(part.strip() for part in text.splitlines() if part.strip())
