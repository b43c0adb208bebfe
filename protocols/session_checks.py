"""The one definition of a valid session record, shared by the writer, the reader and the
validator: types, ranges, finite values, links, and the samples themselves.

Two kinds of finding, kept apart on purpose:

* a **problem** breaks the contract as written (``shared/spec/session-file-v1.md``): a
  missing item, a wrong type, ``repeat`` 0, ``Iemax_mA <= Iemin_mA``, a non-finite value,
  a ratio outside [0, 1]. The reader refuses it and the writer refuses to write it
  (:func:`calibration_findings`, :func:`trial_attr_findings`, :func:`value_problem` are
  called by all three, so they cannot disagree);
* a **warning** is physically implausible but allowed by the contract: a current above the
  recording stimulator's declared range (another stimulator reaches more: a RehaStim2
  130 mA), a force beyond any elbow's, sE above the paper's 1.00, a chirp above Nyquist.
  ``nmsid validate`` prints it and the reader logs it; the file is still read and analysed.

Each line names the item and says what would be valid.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmsid.protocols.session_model import _as_str, _h5py

DEFAULT_MAX_CURRENT_mA = 16.0
"""Above this current a file gets a WARNING (never a refusal) when its stored configuration
names no ceiling: the STG4002's range (Multi Channel Systems STG4000 series manual, 16 mA
per channel), the stimulator of the paper. A file whose ``config_json`` has higher
``ceiling_*_mA`` (other hardware) is compared with those. The contract sets no upper bound
on a current."""
FS_RANGE_Hz = (1.0, 1.0e6)
"""Plausible sampling rates (the paper: 2000 Hz; A/D cards: at most about 1 MHz): outside,
a warning; the contract only needs a rate > 0."""
MAX_TRIAL_S = 3600.0
"""Plausible longest steady_s / chirp_s (warning above; the configuration refuses longer
trials for sessions this rig runs)."""
PLAUSIBLE_FORCE_N = 1000.0
"""Above this |force| (or wrench component) a file gets a warning: more than an elbow
produces and more than the paper's 6-axis sensor's class of ranges (its Fmax was 5 N)."""
MAX_FORCE_N = 1.0e100
"""Largest |force| a sample may have: a numeric bound, not a physical one (a force in N
cannot be larger than any float64 sum of squares over 10**8 samples can hold: beyond it the
identification's least squares overflow to inf). Physical plausibility is
:data:`PLAUSIBLE_FORCE_N`, a warning."""
MAX_CARRIER_Hz = 1.0e6
PLAUSIBLE_SE = 1.0
"""Largest sE of the paper's protocol (0.30 ... 1.00). sE = Ie + If (the paper's Eq. 4) may
exceed it when currents pass Imax: a warning, not a refusal."""
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
    if bad_low and high is None and valid:
        return f"{where} attribute {name} = {x:g} is not valid (valid: {valid})"
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


def _only_hard_links_and_own_storage(f) -> bool:
    """True when every link of the file is hard and no dataset keeps its data elsewhere,
    found through HDF5's own traversal (no h5py object per item: ~5x faster than the
    walk below, which then runs only to name what it found)."""
    h5py = _h5py()
    seen = 0

    def link(name, info):
        nonlocal seen
        seen += 1
        return True if info.type != h5py.h5l.TYPE_HARD or seen > 1_000_000 else None

    if f.id.links.visit(link, info=True):
        return False

    def obj(name, info):
        if info.type == h5py.h5o.TYPE_DATASET:
            plist = h5py.h5d.open(f.id, name).get_create_plist()
            if plist.get_external_count() or plist.get_layout() == h5py.h5d.VIRTUAL:
                return True
        return None

    return not h5py.h5o.visit(f.id, obj, info=True)


def link_problems(f) -> list[str]:
    """External and soft links, external storage and virtual datasets anywhere in the
    file: refused (never followed), so no item is read from another file."""
    if _only_hard_links_and_own_storage(f):
        return []
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


def samples_problems(where: str, d, *, max_current: float, n_max: int | None,
                     warnings: list[str] | None = None) -> list[str]:
    """Read a dataset block by block (verifying its Fletcher-32 checksums) and check its
    values (:func:`value_problem`); implausible values (:func:`value_warning`) and more
    samples than ``n_max`` are appended to ``warnings``."""
    name = d.name.rsplit("/", 1)[-1]
    if n_max is not None and d.shape and d.shape[0] > n_max and warnings is not None:
        warnings.append(f"{where}/{name} has {d.shape[0]} samples, more than the trial's "
                        f"length needs (4 x (steady_s + chirp_s) * fs_Hz + 10**6 = {n_max})")
    out: list[str] = []
    warned = False
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
        problem = value_problem(name, block)
        if problem:
            out.append(f"{where}/{name} {problem}")
            break
        warning = None if warned else value_warning(name, block, max_current)
        if warning and warnings is not None:
            warnings.append(f"{where}/{name} {warning}")
            warned = True
    return out


def value_problem(name: str, block: np.ndarray, max_current: float | None = None) -> str | None:
    """What breaks the contract in the samples ``block`` of dataset ``name`` (words without
    the item's path), or None: rE outside [0, 1] (a ratio, the paper's Eq. 3), a current
    below 0 (an amplitude), a non-finite command; an infinite measurement (NaN is a gap),
    |force| beyond :data:`MAX_FORCE_N`. ``max_current`` is not used here: a current above
    the stimulator's range is :func:`value_warning`'s."""
    if name in ("rE", "I_ext_mA", "I_flex_mA"):
        if not np.isfinite(block).all():
            return "holds NaN or infinite values (valid: finite)"
        if name == "rE":
            if block.size and (block.min() < 0.0 or block.max() > 1.0):
                return (f"holds values in [{block.min():g}, {block.max():g}], outside "
                        "[0, 1] (a ratio)")
        elif block.size and block.min() < 0.0:
            return f"holds values down to {block.min():g}, below 0 (valid: an amplitude >= 0)"
        return None
    if np.isinf(block).any():
        return "holds infinite values (valid: finite, or NaN for a gap)"
    if name in ("force_N", "wrench"):
        peak = _peak(block)
        if peak > MAX_FORCE_N:
            return f"holds |values| up to {peak:g}, beyond {MAX_FORCE_N:g} (valid: a force)"
    return None


def value_warning(name: str, block: np.ndarray, max_current: float) -> str | None:
    """What is implausible (allowed by the contract) in the samples ``block``, or None."""
    if name in ("I_ext_mA", "I_flex_mA"):
        finite = block[np.isfinite(block)]
        if finite.size and finite.max() > max_current:
            return (f"reaches {finite.max():g} mA, above the recording stimulator's declared "
                    f"range {max_current:g} mA (a warning: other stimulators reach more)")
    if name in ("force_N", "wrench"):
        peak = _peak(block)
        if math.isfinite(peak) and peak > PLAUSIBLE_FORCE_N:
            return (f"reaches |{peak:g}| N, beyond {PLAUSIBLE_FORCE_N:g} N (more than an "
                    "elbow produces: a unit or scale error?)")
    return None


def _peak(block: np.ndarray) -> float:
    return float(np.nanmax(np.abs(block))) if block.size and not np.isnan(block).all() \
        else 0.0


@dataclass
class Findings:
    """What a record breaks (``problems``: refused by reader and writer) and what is
    merely implausible (``warnings``: reported, the record is read)."""

    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def calibration_findings(attrs: Mapping[str, Any], max_mA: float = DEFAULT_MAX_CURRENT_mA,
                         where: str = "/calibration") -> Findings:
    """Check the calibration's six attributes (as stored, or as the writer would store them).

    The contract: each a float; ``Iemax_mA > Iemin_mA >= 0`` and ``Ifmax_mA > Ifmin_mA >= 0``
    (its "Required" line); ``Fmin_N`` / ``Fmax_N`` are the forces the currents produced, the
    smaller and the larger (their names: the paper's Fmin, contraction onset, and Fmax, the
    force the ramp rose to), so ``Fmax_N > Fmin_N``. A current above the stimulator's range
    and a force beyond 1000 N or below 0 are warnings.
    """
    out = Findings()
    values: dict[str, float] = {}
    for name in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N"):
        if name not in attrs:
            out.problems.append(f"missing required attribute {where}/{name}")
            continue
        p = number_problem(where, name, attrs[name])
        if p:
            out.problems.append(p)
            continue
        values[name] = float(np.asarray(attrs[name]).reshape(()))
    for hi, lo in (("Iemax_mA", "Iemin_mA"), ("Ifmax_mA", "Ifmin_mA")):
        if {hi, lo} <= set(values) and not values[hi] > values[lo] >= 0:
            out.problems.append(f"{where} needs {hi} > {lo} >= 0, got {lo}="
                                f"{values[lo]:g}, {hi}={values[hi]:g}")
        if hi in values and values[hi] > max_mA:
            out.warnings.append(f"{where} attribute {hi} = {values[hi]:g} is above the "
                                f"recording stimulator's declared range {max_mA:g} mA "
                                "(a warning: other stimulators reach more)")
    if {"Fmin_N", "Fmax_N"} <= set(values) and not values["Fmax_N"] > values["Fmin_N"]:
        out.problems.append(f"{where} needs Fmax_N > Fmin_N, got Fmin_N="
                            f"{values['Fmin_N']:g}, Fmax_N={values['Fmax_N']:g}")
    for name in ("Fmin_N", "Fmax_N"):
        if name in values and not 0 <= values[name] <= PLAUSIBLE_FORCE_N:
            out.warnings.append(f"{where} attribute {name} = {values[name]:g} is outside "
                                f"[0, {PLAUSIBLE_FORCE_N:g}] N (implausible; the paper: "
                                "0.5 and 5 N)")
    return out


#: Per float attribute of a trial: (lowest valid, open?, what is valid) from the contract's
#: meaning (a rate or a frequency > 0, a length >= 0, sE > 0 since rE = Ie / sE), and the
#: plausible upper bound beyond which it is a warning.
TRIAL_BOUNDS: dict[str, tuple[float, bool, str, float]] = {
    "sE": (0.0, True, "> 0 (rE = Ie / sE, the paper's Eq. 3)", PLAUSIBLE_SE),
    "fs_Hz": (0.0, True, "> 0 Hz", FS_RANGE_Hz[1]),
    "steady_s": (0.0, False, ">= 0 s (a length)", MAX_TRIAL_S),
    "chirp_s": (0.0, False, ">= 0 s (a length)", MAX_TRIAL_S),
    "chirp_f0_Hz": (0.0, False, ">= 0 Hz", FS_RANGE_Hz[1] / 2),
    "chirp_f1_Hz": (0.0, False, ">= 0 Hz", FS_RANGE_Hz[1] / 2),
    "carrier_Hz": (0.0, False, ">= 0 Hz", MAX_CARRIER_Hz),
}


def trial_attr_findings(attrs: Mapping[str, Any], where: str) -> Findings:
    """Check a trial's contract attributes (as stored, or as the writer would store them):
    each float attribute a finite number with its meaning's sign (:data:`TRIAL_BOUNDS`),
    ``repeat`` an integer 1, 2, 3, ..., ``status`` ``completed`` or ``aborted``, the strings
    strings UTF-8 text. Beyond the plausible bounds, and non-printable strings, are warnings."""
    out = Findings()
    values: dict[str, float] = {}
    for key, (low, low_open, valid, plausible) in TRIAL_BOUNDS.items():
        if key not in attrs:
            out.problems.append(f"missing required attribute {where}/{key}")
            continue
        p = number_problem(where, key, attrs[key], low, None, low_open=low_open, valid=valid)
        if p:
            out.problems.append(p)
            continue
        values[key] = float(np.asarray(attrs[key]).reshape(()))
        if values[key] > plausible:
            out.warnings.append(f"{where} attribute {key} = {values[key]:g} is above "
                                f"{plausible:g} (implausible for this protocol)")
    for key in ("chirp_f0_Hz", "chirp_f1_Hz"):
        if key in values and "fs_Hz" in values and values[key] > values["fs_Hz"] / 2:
            out.warnings.append(f"{where} attribute {key} = {values[key]:g} is above "
                                f"fs_Hz / 2 = {values['fs_Hz'] / 2:g} (not resolved by "
                                "the samples)")
    if "repeat" not in attrs:
        out.problems.append(f"missing required attribute {where}/repeat")
    elif not is_int_attr(attrs["repeat"]) or int(np.asarray(attrs["repeat"]).reshape(())) < 1:
        out.problems.append(f"{where} attribute repeat = {short_repr(attrs['repeat'])} is not "
                            "valid: an integer 1, 2, 3, ...")
    for key in ("status", "abort_reason", "started_utc"):
        if key not in attrs:
            out.problems.append(f"missing required attribute {where}/{key}")
        elif not _is_str_attr(attrs[key]):
            out.problems.append(f"{where} attribute {key} = {short_repr(attrs[key])} is not "
                                "a string")
        else:
            p = printable_problem(where, key, attrs[key])
            if p:
                out.warnings.append(p)
    if "status" in attrs and _is_str_attr(attrs["status"]) and \
            _as_str(attrs["status"]) not in ("completed", "aborted"):
        out.problems.append(f"{where} status {_as_str(attrs['status'])!r} is not "
                            "'completed' or 'aborted'")
    return out


def _is_str_attr(value: Any) -> bool:
    if isinstance(value, (str, bytes, np.bytes_, np.str_)):
        return True
    arr = np.asarray(value)
    return arr.shape == () and arr.dtype.kind in "OSU" and \
        isinstance(arr[()], (str, bytes))
