"""Value checks shared by the session-file reader and validator: types, ranges, finite
values, printable strings, links, and the samples themselves.

Every function appends one line per problem to ``out``; each line names the item and
says what would be valid. The bounds are physical: no session of this protocol needs
more, and a value beyond them is a typo or a damaged file.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import numpy as np

from nmsid.protocols.session_model import _as_str, _h5py

DEFAULT_MAX_CURRENT_mA = 16.0
"""Highest current a file may hold when its stored configuration names no ceiling: the
STG4002's range (Multi Channel Systems STG4000 series manual, 16 mA per channel), the
stimulator of the paper. A file whose ``config_json`` has higher ``ceiling_*_mA`` (other
hardware) is checked against those."""
FS_RANGE_Hz = (1.0, 1.0e6)
"""Sampling rates a trial may have (the paper: 2000 Hz; A/D cards: at most about 1 MHz)."""
MAX_TRIAL_S = 3600.0
"""Longest steady_s + chirp_s (the configuration refuses longer trials too)."""
MAX_FORCE_N = 1.0e12
"""Largest |force| (and wrench component, N or N m) a sample may have. Not a sensor
range (those are far lower; the interlock guards them during a session) but a bound
against damage and unit errors (force x 1e300) that would overflow the identification."""
MAX_CARRIER_Hz = 1.0e6
READ_BLOCK = 1 << 20
"""Samples read at a time when checking data (bounded memory whatever a file declares)."""
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def is_number_attr(value: Any) -> bool:
    """True for a numeric scalar attribute (int / float; not a string, bool or array)."""
    arr = np.asarray(value)
    return arr.size == 1 and arr.dtype.kind in "iuf"


def is_int_attr(value: Any) -> bool:
    arr = np.asarray(value)
    return arr.size == 1 and arr.dtype.kind in "iu"


def number_problem(where: str, name: str, value: Any, low: float | None = None,
                   high: float | None = None, *, low_open: bool = False,
                   valid: str = "") -> str | None:
    """The problem with a float attribute (type, finiteness, range), or None."""
    if not is_number_attr(value):
        return (f"{where} attribute {name} = {short_repr(value)} is not a number "
                f"(valid: a float{', ' + valid if valid else ''})")
    x = float(np.asarray(value).reshape(()))
    if not math.isfinite(x):
        return f"{where} attribute {name} = {x!r} is not a finite number"
    bad_low = low is not None and (x <= low if low_open else x < low)
    if bad_low or (high is not None and x > high):
        shown = valid or _range(low, high, low_open)
        return f"{where} attribute {name} = {x:g} is outside {shown}"
    return None


def _range(low, high, low_open) -> str:
    return f"{'(' if low_open else '['}{low:g}, {high:g}]" if high is not None \
        else f"{'>' if low_open else '>='} {low:g}"


def short_repr(value: Any) -> str:
    """``repr`` of an attribute value, plain (no ``np.float64(...)``), at most 60 chars."""
    if isinstance(value, (bytes, np.bytes_)):
        value = _as_str(value)
    elif isinstance(value, np.generic):
        value = value.item()
    elif isinstance(value, np.ndarray):
        value = value.tolist() if value.size <= 8 else f"array of shape {value.shape}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def printable_problem(where: str, name: str, value: Any) -> str | None:
    """The problem with a string attribute: not a string, or non-printable characters
    (terminal escapes, newlines) that would reach a terminal, a file name or a report."""
    if not isinstance(value, (str, bytes, np.bytes_, np.str_)):
        arr = np.asarray(value)
        if not (arr.shape == () and arr.dtype.kind in "OSU"):
            return f"{where} attribute {name} = {short_repr(value)} is not a string"
    text = _as_str(value)
    if _CONTROL.search(text):
        return (f"{where} attribute {name} = {short_repr(text)} holds non-printable characters "
                "(control codes, newlines or terminal escapes); valid: printable text")
    return None


def max_current_mA(config_json: str) -> float:
    """The highest current the file may hold: its configuration's ``ceiling_*_mA`` (the
    larger), else :data:`DEFAULT_MAX_CURRENT_mA`."""
    try:
        cal = json.loads(config_json).get("calibration", {})
        ceilings = [float(cal[k]) for k in ("ceiling_ext_mA", "ceiling_flex_mA") if k in cal]
    except (ValueError, TypeError, AttributeError):
        ceilings = []
    ceilings = [c for c in ceilings if math.isfinite(c) and 0 < c <= 1000]
    return max(ceilings) if ceilings else DEFAULT_MAX_CURRENT_mA


def link_problems(f) -> list[str]:
    """External and soft links, external storage and virtual datasets anywhere in the
    file: refused (never followed), so no item is read from another file."""
    h5py = _h5py()
    out: list[str] = []
    seen = 0

    def visit(name, link):
        nonlocal seen
        seen += 1
        if isinstance(link, h5py.ExternalLink):
            out.append(f"/{name} is an external link to {link.filename}:{link.path}; "
                       "refused (a session file holds its own data; links are not followed)")
        elif isinstance(link, h5py.SoftLink):
            out.append(f"/{name} is a soft link to {link.path}; refused (a session file "
                       "holds each item once, as itself)")
        elif seen > 1_000_000:
            raise OverflowError("more than a million objects")

    try:
        f.visititems_links(visit)
    except OverflowError:
        out.append("the file holds more than a million objects; not a session file")
        return out
    if out:
        return out

    def datasets(name, obj):
        if isinstance(obj, h5py.Dataset):
            if obj.external:
                out.append(f"/{name} keeps its data in external file(s) "
                           f"{[e[0] for e in obj.external][:3]}; refused (not followed)")
            elif obj.is_virtual:
                out.append(f"/{name} is a virtual dataset (data in other files); refused")

    f.visititems(datasets)
    return out


def samples_problems(where: str, d, *, max_current: float, n_max: int | None) -> list[str]:
    """Read a dataset block by block (verifying its Fletcher-32 checksums) and check its
    values: rE in [0, 1], currents in [0, max_current], all finite; force / wrench finite
    or NaN (a gap) and within +-:data:`MAX_FORCE_N`; sync finite or NaN."""
    name = d.name.rsplit("/", 1)[-1]
    if n_max is not None and d.shape and d.shape[0] > n_max:
        return [f"{where}/{name} has {d.shape[0]} samples, more than the trial's "
                f"length allows (at most 4 x (steady_s + chirp_s) * fs_Hz + 10**6 = {n_max})"]
    out: list[str] = []
    n = d.shape[0] if d.shape else 1
    scale = offset = None
    if d.dtype.kind in "iu" and "scale" in d.attrs:
        scale, offset = d.attrs["scale"], d.attrs.get("offset", 0.0)
    elif d.dtype.kind not in "f":
        return out  # the structural checks report the type
    for lo in range(0, max(n, 1), READ_BLOCK):
        try:
            block = np.asarray(d[lo:lo + READ_BLOCK] if d.shape else d[()], dtype=np.float64)
        except (OSError, RuntimeError, ValueError, KeyError) as exc:
            return [f"{where}/{name} is damaged: its data cannot be read ({exc}); a "
                    "checksum mismatch means the file changed on disk"]
        if scale is not None:
            block = block * np.asarray(scale, dtype=np.float64) + np.asarray(offset,
                                                                             dtype=np.float64)
        problem = value_problem(name, block, max_current)
        if problem:
            out.append(f"{where}/{name} {problem}")
            break
    return out


def value_problem(name: str, block: np.ndarray, max_current: float) -> str | None:
    """What is wrong with the samples ``block`` of dataset ``name`` (words without the
    item's path), or None."""
    if name in ("rE", "I_ext_mA", "I_flex_mA"):
        if not np.isfinite(block).all():
            return "holds NaN or infinite values (valid: finite)"
        low, high = (0.0, 1.0) if name == "rE" else (0.0, max_current)
        if block.size and (block.min() < low or block.max() > high):
            return (f"holds values in [{block.min():g}, {block.max():g}], outside "
                    f"[{low:g}, {high:g}]")
        return None
    if np.isinf(block).any():
        return "holds infinite values (valid: finite, or NaN for a gap)"
    if name in ("force_N", "wrench"):
        peak = np.nanmax(np.abs(block)) if block.size and not np.isnan(block).all() else 0.0
        if peak > MAX_FORCE_N:
            return f"holds |values| up to {peak:g}, beyond {MAX_FORCE_N:g} (valid: a force)"
    return None
