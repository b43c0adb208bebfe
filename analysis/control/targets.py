"""Force targets of tracking trials: steps, ramps and sines (0.2-2 Hz), or a CSV.

Every target starts with ``lead_s`` at its first value (the force goes there from rest;
metrics leave the lead-in out) and is held over each stream update. A target is stored
with its trial as ``target_json`` (its definition: a CSV's knots), so the report can
rebuild it sample by sample.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nmsid.analysis.control.errors import ControllerFileError

LEAD_S = 1.0
"""Lead-in of every target at its first value (left out of the metrics)."""
MAX_CSV_ROWS = 2500
"""A CSV target is stored in the session file as a trial attribute (below HDF5's 64 kB
limit of a compact attribute): at most this many rows."""
SINE_FREQUENCIES_HZ = (0.2, 0.5, 1.0, 2.0)
RANGE_FRACTION = 0.7
"""Default targets span this fraction of the force range the twin predicts at the
controller's sE (offset +- Kp / 2 over rE in [0, 1]): headroom for the feedback."""


@dataclass(frozen=True)
class Target:
    """One force target."""

    name: str
    kind: str
    """``step``, ``ramp``, ``sine`` or ``csv``."""
    params: dict = field(default_factory=dict)
    duration_s: float = 0.0
    """Without the lead-in."""
    lead_s: float = LEAD_S

    def force_at(self, t_s: np.ndarray) -> np.ndarray:
        """Target force at times ``t_s`` after the trial start (lead-in included)."""
        t = np.asarray(t_s, dtype=float) - self.lead_s
        p = self.params
        tt = np.clip(t, 0.0, self.duration_s)
        if self.kind == "step":
            levels = np.asarray(p["levels_N"], dtype=float)
            k = np.minimum((tt / p["hold_s"]).astype(int), levels.size - 1)
            return levels[k]
        if self.kind == "ramp":
            lo, hi, T = p["low_N"], p["high_N"], self.duration_s
            frac = 1.0 - np.abs(2.0 * tt / T - 1.0)
            return lo + (hi - lo) * frac
        if self.kind == "sine":
            return p["mean_N"] - p["amplitude_N"] * np.cos(2 * math.pi * p["f_Hz"] * tt)
        if self.kind == "csv":
            return np.interp(tt, p["t_s"], p["force_N"])
        raise ControllerFileError(f"target {self.name!r}: kind {self.kind!r} is unknown; "
                                  "valid: step, ramp, sine, csv")

    def samples(self, rate_Hz: float) -> np.ndarray:
        """The target held over each update at ``rate_Hz`` (value at the update's middle)."""
        n = round((self.lead_s + self.duration_s) * rate_Hz)
        return self.force_at((np.arange(n) + 0.5) / rate_Hz)

    @property
    def range_N(self) -> float:
        f = self.force_at(np.linspace(0, self.lead_s + self.duration_s, 2001))
        return float(f.max() - f.min())

    def to_json(self) -> str:
        return json.dumps({"name": self.name, "kind": self.kind, "params": self.params,
                           "duration_s": self.duration_s, "lead_s": self.lead_s},
                          separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Target:
        d = json.loads(text)
        return cls(name=d["name"], kind=d["kind"], params=d["params"],
                   duration_s=float(d["duration_s"]), lead_s=float(d["lead_s"]))


def default_targets(low_N: float, high_N: float) -> list[Target]:
    """Steps, a ramp and sines at 0.2, 0.5, 1 and 2 Hz within ``[low_N, high_N]``."""
    lo, hi = float(low_N), float(high_N)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    out = [Target("steps", "step", {"levels_N": [mid, hi, lo, mid + 0.5 * half, mid],
                                    "hold_s": 1.5}, 7.5)]
    out.append(Target("ramp", "ramp", {"low_N": lo, "high_N": hi}, 6.0))
    for f in SINE_FREQUENCIES_HZ:
        periods = 2 if f < 0.5 else 3
        out.append(Target(f"sine-{f:g}Hz", "sine",
                          {"mean_N": mid, "amplitude_N": half, "f_Hz": f}, periods / f))
    return out


def load_target_csv(path) -> Target:
    """A target from a CSV with columns ``t_s,force_N`` (a header row), t from 0, increasing.

    Raises
    ------
    ControllerFileError
        One line naming the file, the row and what is valid.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ControllerFileError(f"{p}: cannot read the target CSV ({exc})") from None
    rows = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
    if not rows or [c.strip() for c in rows[0]] != ["t_s", "force_N"]:
        raise ControllerFileError(f"{p}: the first row must be the header 't_s,force_N'")
    t, f = [], []
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != 2:
            raise ControllerFileError(f"{p}: row {i} has {len(r)} columns; expected 2 "
                                      "(t_s,force_N)")
        try:
            ti, fi = float(r[0]), float(r[1])
        except ValueError:
            raise ControllerFileError(f"{p}: row {i}: {r!r} are not numbers") from None
        if not (math.isfinite(ti) and math.isfinite(fi)):
            raise ControllerFileError(f"{p}: row {i}: values must be finite")
        t.append(ti)
        f.append(fi)
    if len(t) < 2:
        raise ControllerFileError(f"{p}: needs at least 2 rows of t_s,force_N")
    if len(t) > MAX_CSV_ROWS:
        raise ControllerFileError(f"{p}: {len(t)} rows; at most {MAX_CSV_ROWS} (the target is "
                                  "stored with each trial); resample it")
    if t[0] != 0.0 or any(b <= a for a, b in itertools.pairwise(t)):
        raise ControllerFileError(f"{p}: t_s must start at 0 and increase strictly")
    return Target(p.stem, "csv", {"t_s": t, "force_N": f}, float(t[-1]))
