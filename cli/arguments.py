"""argparse types shared by the sub-commands: paths and integers refused in one line
(exit 2, naming the value and what is valid) while the command line is read, before any
file is opened or any device connected.

Registration-level (imported by ``nmsid --help``): standard library only.
"""

from __future__ import annotations

import argparse
import os
import re
import stat

from nmsid.protocols.user_values import (
    SEED_MAX,
    name_length_problem,
    non_utf8_problem,
    parse_seed,
    shown,
)


def input_file(text: str) -> str:
    """A file to read: not empty, not a folder, and if it exists a regular file (a FIFO,
    a device or a socket is refused before anything reads it: reading one waits forever);
    a missing file is left to the command, which names it."""
    problem = non_utf8_problem(text) or _input_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def _input_problem(text: str) -> str | None:
    if not text.strip():
        return "an empty file name; give the path of a session file (.h5)"
    try:
        st = os.stat(text)
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{text}: {exc.strerror}"
    if stat.S_ISDIR(st.st_mode):
        return f"{text} is a folder; give a session file (.h5) inside it"
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else
                "a socket" if stat.S_ISSOCK(st.st_mode) else "a device")
        return f"{text} is {kind}, not a regular file; nothing was read from it"
    return None


def input_path(text: str) -> str:
    """A file or folder to read (``nmsid study``'s STUDY.toml or FOLDER): not empty, a
    UTF-8 name, not a FIFO or device."""
    problem = non_utf8_problem(text)
    if not problem and not text.strip():
        problem = "an empty path; give a study file (.toml) or a folder of sessions"
    if not problem:
        try:
            st = os.stat(text)
            if not (stat.S_ISDIR(st.st_mode) or stat.S_ISREG(st.st_mode)):
                problem = f"{text} is not a regular file or a folder; nothing was read"
        except OSError:
            pass
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def output_path(text: str) -> str:
    """A file or folder to write: not empty, a UTF-8 name (the reports, the journal and
    the NWB file name it), and short enough for the names derived from it."""
    problem = non_utf8_problem(text) or name_length_problem(text)
    if not problem and not text.strip():
        problem = "an empty path; give a file or folder to write"
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def seed(text: str) -> int:
    """A seed: a whole number in [0, 2**63 - 1] (stored as a 64-bit integer), the same
    bound as in the GUI's seed field."""
    value, problem = parse_seed(text)
    if problem or value is None:
        raise argparse.ArgumentTypeError(problem or f"give a seed in [0, {SEED_MAX}]")
    return value


def bounded_int(low: int, high: int, what: str = ""):
    """An argparse type: a whole number in [low, high], refused in one line otherwise."""

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give "
                                             f"{low} ... {high}{what}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} is outside [{low}, {high}]{what}")
        return value

    parse.__name__ = "whole number"
    return parse


def session_to_continue(text: str) -> str:
    """A session file that ``recover`` or ``run --resume`` will write beside (journal,
    aside names): an :func:`input_file` whose name leaves room for the derived names."""
    input_file(text)
    problem = name_length_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(problem + "; rename it (and its .journal folder)")
    return text


def folder_to_write(text: str) -> str:
    """A folder to write into: not empty, a UTF-8 name."""
    problem = non_utf8_problem(text)
    if not problem and not text.strip():
        problem = "an empty folder name; give a folder to write"
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


_DURATION = re.compile(r"P(?=\d|T\d)(\d+Y)?(\d+M)?(\d+W)?(\d+D)?"
                       r"(T(?=\d)(\d+H)?(\d+M)?(\d+(\.\d+)?S)?)?")


def iso_age(text: str) -> str:
    """An age as NWB wants it: an ISO 8601 duration (``P30Y``, ``P30Y6M``) or a range of
    two (``P25Y/P35Y``; ``P18Y/``: 18 or older)."""
    parts = text.split("/")
    ok = 1 <= len(parts) <= 2 and _DURATION.fullmatch(parts[0]) is not None and (
        len(parts) == 1 or parts[1] == "" or _DURATION.fullmatch(parts[1]) is not None)
    if not ok:
        raise argparse.ArgumentTypeError(
            f"{shown(text)!r} is not an ISO 8601 duration; give e.g. P30Y (30 years), "
            "P30Y6M, a range P25Y/P35Y, or P18Y/ (18 or older)")
    return text


def non_empty_text(text: str) -> str:
    """Free text that must say something (a name): not empty or blank, printable."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty value; give a name, e.g. 'Last, First'")
    if non_utf8_problem(text) or any(ord(c) < 32 or 127 <= ord(c) < 160 for c in text):
        raise argparse.ArgumentTypeError(f"{shown(text)!r} holds non-printable characters "
                                         "or bytes that are not UTF-8; give plain text")
    return text
