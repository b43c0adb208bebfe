"""Calibration of the two muscles (pure): ramp plans, Imin / Imax detection, manual entry.

Per muscle, alone, the current rises in ``step_mA`` steps (0.5 mA in the paper); each step
is held ``hold_s`` and its force is the mean over the settled part of the hold, minus the
zero-current baseline. The extensor pushes (force > 0), the flexor pulls (force < 0), so
the detection works on ``sign * force``. Imin is the first step whose force reaches
``Fmin_N``, Imax the first step that reaches ``Fmax_N`` (the paper's definitions).

Examples
--------
>>> import numpy as np
>>> cur = np.array([0.5, 1.0, 1.5, 2.0, 2.5])
>>> force = np.array([0.0, 0.2, 0.6, 3.0, 5.5])
>>> r = detect_thresholds(cur, force, Muscle.EXTENSOR, Fmin_N=0.5, Fmax_N=5.0)
>>> (r.Imin_mA, r.Imax_mA)
(1.5, 2.5)
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from nmsid.protocols.config import CalibrationConfig, ManualCurrents
from nmsid.protocols.errors import CalibrationError
from nmsid.protocols.session_file import Calibration


class Muscle(enum.Enum):
    EXTENSOR = "extensor"
    FLEXOR = "flexor"

    @property
    def sign(self) -> int:
        """+1 for the extensor (pushes, extension positive), -1 for the flexor (pulls)."""
        return 1 if self is Muscle.EXTENSOR else -1

    @property
    def prefix(self) -> str:
        """``ext`` / ``flex``: names the ramp datasets and the currents."""
        return "ext" if self is Muscle.EXTENSOR else "flex"


def ramp_currents_mA(cfg: CalibrationConfig, muscle: Muscle) -> np.ndarray:
    """The planned ramp: ``step, 2 step, ...`` up to the muscle's current ceiling."""
    ceiling = cfg.ceiling_ext_mA if muscle is Muscle.EXTENSOR else cfg.ceiling_flex_mA
    n = int(np.floor(ceiling / cfg.step_mA + 1e-9))
    return np.round(cfg.step_mA * np.arange(1, n + 1), 9)


def step_samples(cfg: CalibrationConfig, fs_Hz: float) -> int:
    """Samples in one ramp step."""
    return max(1, int(round(cfg.hold_s * fs_Hz)))


def step_envelopes(cfg: CalibrationConfig, muscle: Muscle, current_mA: float,
                   fs_Hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(I_ext_mA, I_flex_mA) of one ramp step: the muscle at ``current_mA``, the other 0."""
    n = step_samples(cfg, fs_Hz)
    on = np.full(n, float(current_mA))
    off = np.zeros(n)
    return (on, off) if muscle is Muscle.EXTENSOR else (off, on)


def settled_mean_N(force_N, settle_fraction: float) -> float:
    """Mean force over the settled part of a hold (the first ``settle_fraction`` dropped)."""
    f = np.asarray(force_N, dtype=float)
    if f.size == 0:
        return float("nan")
    k = min(int(np.floor(settle_fraction * f.size)), f.size - 1)
    return float(np.mean(f[k:]))


@dataclass(frozen=True)
class Thresholds:
    """Imin / Imax found on one ramp (None: not reached yet)."""

    Imin_mA: float | None
    Imax_mA: float | None

    @property
    def complete(self) -> bool:
        return self.Imin_mA is not None and self.Imax_mA is not None


def detect_thresholds(currents_mA, forces_N, muscle: Muscle, Fmin_N: float, Fmax_N: float
                      ) -> Thresholds:
    """Imin (first step with sign*force >= Fmin_N) and Imax (first step >= Fmax_N).

    Parameters
    ----------
    currents_mA, forces_N : array_like
        The ramp so far, in the order it ran; forces already baseline-corrected, N,
        extension positive.
    muscle : Muscle
        Gives the sign: the flexor's force is negative.
    """
    cur = np.asarray(currents_mA, dtype=float)
    f = muscle.sign * np.asarray(forces_N, dtype=float)
    if cur.shape != f.shape:
        raise CalibrationError(f"ramp currents ({cur.shape}) and forces ({f.shape}) differ "
                               "in length")
    above_min = np.flatnonzero(f >= Fmin_N)
    above_max = np.flatnonzero(f >= Fmax_N)
    imin = float(cur[above_min[0]]) if above_min.size else None
    imax = float(cur[above_max[0]]) if above_max.size else None
    return Thresholds(imin, imax)


def require_thresholds(currents_mA, forces_N, muscle: Muscle, cfg: CalibrationConfig
                       ) -> tuple[float, float]:
    """Like :func:`detect_thresholds` but refuse an incomplete or degenerate ramp.

    Raises
    ------
    CalibrationError
        If Fmin or Fmax was not reached, or both in the same step (Imax must exceed Imin).
    """
    th = detect_thresholds(currents_mA, forces_N, muscle, cfg.Fmin_N, cfg.Fmax_N)
    last = float(np.asarray(currents_mA)[-1]) if len(currents_mA) else 0.0
    if th.Imin_mA is None:
        raise CalibrationError(
            f"{muscle.value} ramp never reached Fmin = {cfg.Fmin_N:g} N (up to {last:g} mA); "
            "check the electrodes, raise the current ceiling, or enter the currents by hand")
    if th.Imax_mA is None:
        raise CalibrationError(
            f"{muscle.value} ramp reached Fmin at {th.Imin_mA:g} mA but never Fmax = "
            f"{cfg.Fmax_N:g} N (up to {last:g} mA); raise the current ceiling or enter the "
            "currents by hand")
    if not th.Imax_mA > th.Imin_mA:
        raise CalibrationError(
            f"{muscle.value} force jumped from below Fmin to Fmax in one step at "
            f"{th.Imax_mA:g} mA; use a smaller step_mA or enter the currents by hand")
    return th.Imin_mA, th.Imax_mA


def make_calibration(ext: tuple[float, float], flex: tuple[float, float],
                     cfg: CalibrationConfig, ramps: dict | None = None):
    """A :class:`nmsid.protocols.session_file.Calibration` from (Imin, Imax) per muscle."""
    cal = Calibration(Iemin_mA=float(ext[0]), Iemax_mA=float(ext[1]),
                      Ifmin_mA=float(flex[0]), Ifmax_mA=float(flex[1]),
                      Fmin_N=cfg.Fmin_N, Fmax_N=cfg.Fmax_N, ramps=dict(ramps or {}))
    check_calibration(cal, cfg)
    return cal


def manual_calibration(manual: ManualCurrents, cfg: CalibrationConfig):
    """The calibration entered by hand (validated against the ceilings)."""
    return make_calibration((manual.Iemin_mA, manual.Iemax_mA),
                            (manual.Ifmin_mA, manual.Ifmax_mA), cfg)


def check_calibration(cal, cfg: CalibrationConfig) -> None:
    """Refuse a calibration that breaks the contract or a current ceiling.

    Raises
    ------
    CalibrationError
    """
    problems = cal.problems()
    if cal.Iemax_mA > cfg.ceiling_ext_mA:
        problems.append(f"Iemax_mA = {cal.Iemax_mA:g} mA is above the extensor ceiling "
                        f"{cfg.ceiling_ext_mA:g} mA")
    if cal.Ifmax_mA > cfg.ceiling_flex_mA:
        problems.append(f"Ifmax_mA = {cal.Ifmax_mA:g} mA is above the flexor ceiling "
                        f"{cfg.ceiling_flex_mA:g} mA")
    if problems:
        raise CalibrationError("calibration refused: " + "; ".join(problems))
