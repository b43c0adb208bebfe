"""Short text forms of the objects a user holds in a notebook or a shell.

A session or a result holds whole arrays; its ``repr`` says what it is in one line, as
MNE's ``<Raw | ...>`` does: ``<Session | P01, 45 trials, 2000 Hz, ...>``, never longer
than :data:`REPR_MAX_CHARS`. ``_repr_html_`` is the same text for Jupyter. Tables (the
identified parameters, the gap verdicts) are offered as :func:`rows` (a list of dicts,
standard library only) and, when pandas is installed, as a ``pandas.DataFrame``
(:func:`to_dataframe`; pandas is optional and imported only there).
"""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Sequence
from typing import Any

from nmsid.errors import MissingDependency
from nmsid.protocols.printable import escape_controls

#: The longest repr of any object nmsid returns (issue 38: a session's was 100,331
#: characters, a result's 201,733).
REPR_MAX_CHARS = 2000


def short_repr(kind: str, *parts: str) -> str:
    """``<kind | part, part, ...>``: empty parts left out, control characters escaped,
    cut to :data:`REPR_MAX_CHARS`.

    Examples
    --------
    >>> short_repr("Session", "P01", "", "45 trials")
    '<Session | P01, 45 trials>'
    """
    body = ", ".join(p for p in parts if p)
    text = escape_controls(f"<{kind} | {body}>" if body else f"<{kind}>")
    if len(text) > REPR_MAX_CHARS:
        text = text[:REPR_MAX_CHARS - 4] + "...>"
    return text


def html_repr(obj: object) -> str:
    """The object's repr as HTML (Jupyter's ``_repr_html_``), escaped."""
    return "<pre>" + html.escape(repr(obj)) + "</pre>"


def number_span(values: Iterable[float], fmt: str = "g") -> str:
    """``"0.3-1"`` (the smallest and largest finite value), ``"0.5"`` (one) or ``""``."""
    finite = sorted(float(v) for v in values if v is not None and math.isfinite(float(v)))
    if not finite:
        return ""
    lo, hi = finite[0], finite[-1]
    return format(lo, fmt) if lo == hi else f"{lo:{fmt}}-{hi:{fmt}}"


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``"1 trial"``, ``"3 trials"``."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def names(items: Sequence[str], most: int = 4) -> str:
    """The first ``most`` names, then how many more."""
    shown = ", ".join(str(i) for i in items[:most])
    return shown + (f" and {len(items) - most} more" if len(items) > most else "")


def to_dataframe(rows: list[dict[str, Any]]) -> Any:
    """A ``pandas.DataFrame`` of ``rows``.

    Raises
    ------
    MissingDependency
        If pandas is not installed (``.rows()`` gives the same table without it).
    """
    try:
        import pandas as pd  # optional: only a DataFrame needs it
    except ImportError as exc:
        raise MissingDependency(f"to_dataframe() needs pandas, which cannot be imported "
                                f"({exc}; pip install pandas); .rows() gives the same "
                                "table as a list of dicts") from None
    return pd.DataFrame(rows)
