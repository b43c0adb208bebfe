"""Candidate protocols: configurations the engine runs unchanged, and the search space.

A candidate is a handful of protocol settings (sE levels, repeats, lead-in, excitation
kind, length, band, amplitude, rest). :meth:`Candidate.config` turns it into a
``protocols.config.Config`` through the same loader and checks as a TOML file, so a
candidate that breaks a rule (a level outside (0, 1], a band at Nyquist, rE outside
[0, 1], too few multisine tones for the band) cannot be proposed. The currents stay below
the calibration's Imax (hence below the ceilings) for every candidate because rE stays in
[0, 1] and sE <= 1: the same argument as for the paper's chirp.

Stimulation seconds count the time current flows: levels x repeats x (lead-in +
excitation). Session length adds the rests between trials (calibration not included; it
is the same for every protocol).

Examples
--------
>>> paper_candidate().stimulation_s
675.0
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from nmsid.protocols.config import Config, config_from_dict

PAPER_LEVELS = tuple(round(0.30 + 0.05 * k, 2) for k in range(15))


@dataclass(frozen=True)
class Candidate:
    """One protocol the designer may propose (field names as in ``[protocol]``)."""

    sE_levels: tuple[float, ...] = PAPER_LEVELS
    repeats: int = 3
    steady_s: float = 5.0
    chirp_s: float = 10.0
    chirp_f0_Hz: float = 1.0
    chirp_f1_Hz: float = 10.0
    rE_amplitude: float = 0.5
    input_kind: str = "chirp"
    multisine_tones: int = 24
    rest_s: float = 60.0
    label: str = ""

    @property
    def n_trials(self) -> int:
        return len(self.sE_levels) * self.repeats

    @property
    def trial_s(self) -> float:
        return self.steady_s + self.chirp_s

    @property
    def stimulation_s(self) -> float:
        return float(self.n_trials * self.trial_s)

    @property
    def session_s(self) -> float:
        """Trials plus rests between them (calibration excluded)."""
        return float(self.stimulation_s + max(self.n_trials - 1, 0) * self.rest_s)

    def protocol_dict(self) -> dict:
        """The ``[protocol]`` table of a configuration file."""
        d = {"sE_levels": [float(v) for v in self.sE_levels], "repeats": int(self.repeats),
             "steady_s": float(self.steady_s), "chirp_s": float(self.chirp_s),
             "chirp_f0_Hz": float(self.chirp_f0_Hz), "chirp_f1_Hz": float(self.chirp_f1_Hz),
             "rE_amplitude": float(self.rE_amplitude), "rest_s": float(self.rest_s),
             "input_kind": self.input_kind}
        if self.input_kind == "multisine":
            d["multisine_tones"] = int(self.multisine_tones)
        return d

    def config(self, source: str = "nmsid design candidate") -> Config:
        """The validated configuration (raises ``ConfigError`` if any rule is broken)."""
        return config_from_dict({"protocol": self.protocol_dict()}, source=source)

    def describe(self) -> str:
        kind = ("chirp" if self.input_kind == "chirp"
                else f"multisine ({self.multisine_tones} tones)")
        return (f"{len(self.sE_levels)} sE levels x {self.repeats} repeat(s), "
                f"{self.steady_s:g} s lead-in + {self.chirp_s:g} s {kind} "
                f"{self.chirp_f0_Hz:g}-{self.chirp_f1_Hz:g} Hz, amplitude "
                f"{self.rE_amplitude:g}")


def paper_candidate(rest_s: float = 60.0) -> Candidate:
    """The paper's protocol: 15 levels x 3 repeats, 5 s at rE = 0.5 + 10 s chirp 1-10 Hz."""
    return Candidate(rest_s=rest_s, label="paper")


#: Level sets on the paper's 0.05 grid. "even": spread over 0.30-1.00; "clustered": pairs
#: at both ends and in the middle, nearer the minimax design of a quadratic curve (ends and
#: centre) while keeping the distinct levels AICc needs (5 for a quadratic).
LEVEL_SETS = {
    "even15": PAPER_LEVELS,
    "even8": (0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.00),
    "even6": (0.30, 0.45, 0.60, 0.70, 0.85, 1.00),
    "clustered9": (0.30, 0.35, 0.40, 0.60, 0.65, 0.70, 0.90, 0.95, 1.00),
    "clustered7": (0.30, 0.35, 0.60, 0.65, 0.70, 0.95, 1.00),
    "clustered6": (0.30, 0.35, 0.60, 0.70, 0.95, 1.00),
}


#: Rest after a trial per second of its stimulation: the paper rests 60 s after 15 s
#: trials (a 20 % duty cycle); a designed protocol keeps that duty cycle against fatigue.
REST_PER_STIM_S = 4.0

#: Shortest rest between trials whatever the trial length (electrode and skin checks).
MIN_REST_S = 10.0


def rest_for(trial_s: float, rest_per_stim_s: float = REST_PER_STIM_S) -> float:
    """Rest after a trial of ``trial_s`` seconds: the paper's duty cycle, at least 10 s."""
    return float(max(MIN_REST_S, round(rest_per_stim_s * trial_s, 1)))


def search_space(*, min_steady_s: float = 2.0, rest_per_stim_s: float = REST_PER_STIM_S,
                 durations_s=(4.0, 6.0, 8.0, 10.0, 12.0),
                 bands_Hz=((1.0, 10.0), (1.0, 12.0), (0.8, 8.0), (1.5, 10.0)),
                 amplitudes=(0.35, 0.5), kinds=("chirp", "multisine"),
                 repeats=(1, 2, 3, 4, 5), level_sets=None) -> list[Candidate]:
    """Every candidate of the grid, sorted by stimulation seconds.

    The lead-in is ``min_steady_s`` for every candidate: under the model it carries no
    information (the fit starts after it and estimates the initial state), so a longer one
    only costs stimulation. Excitations are at least 4 s: the lowest tone (about 1 Hz)
    then completes several cycles, and the identification loses a few tenths of a second to
    filter edges at each end. Multisines use 24 tones or as many as the band holds (at least
    6). Rests keep the paper's duty cycle (:func:`rest_for`).
    """
    sets = LEVEL_SETS if level_sets is None else level_sets
    out = []
    for (name, levels), r, T, (f0, f1), a, kind in itertools.product(
            sets.items(), repeats, durations_s, bands_Hz, amplitudes, kinds):
        tones = 24
        if kind == "multisine":
            available = math.floor(f1 * T + 1e-9) - math.ceil(f0 * T - 1e-9) + 1
            tones = min(24, available)
            if tones < 6:
                continue
        out.append(Candidate(sE_levels=tuple(levels), repeats=r, steady_s=min_steady_s,
                             chirp_s=T, chirp_f0_Hz=f0, chirp_f1_Hz=f1, rE_amplitude=a,
                             input_kind=kind, multisine_tones=tones,
                             rest_s=rest_for(min_steady_s + T, rest_per_stim_s),
                             label=name))
    out.sort(key=lambda c: (c.stimulation_s, c.session_s, -c.rE_amplitude))
    return out


def with_paper_excitation(candidates: list[Candidate], paper: Candidate | None = None
                          ) -> list[Candidate]:
    """The candidates whose excitation is the paper's (same input kind, length, band and
    amplitude); lead-in, levels, repeats and rests stay free.

    For a participant that is not second order the best second-order description depends
    on the excitation, so only these give the twin the paper's protocol would give.
    """
    ref = paper or paper_candidate()
    key = (ref.input_kind, ref.chirp_s, ref.chirp_f0_Hz, ref.chirp_f1_Hz, ref.rE_amplitude)
    return [c for c in candidates
            if (c.input_kind, c.chirp_s, c.chirp_f0_Hz, c.chirp_f1_Hz, c.rE_amplitude) == key]
