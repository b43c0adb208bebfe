"""The two force controllers a tracking session compares, and the relay auto-tuning.

Both run at the stream's update period ``Ts_s`` and command rE in [0, 1] at a fixed sE
(the currents follow from the calibration, paper eqs. 1-4). The loop's timing is the
streamed stimulator's: after the force of update ``j`` is read, the controller decides
update ``j + queue`` (``queue`` updates are already queued ahead, so a decision never
arrives late). A step gets the mean force over update ``j`` (less noise than one sample).

* :class:`TwinController` (designed from the twin, :mod:`nmsid.analysis.control.design`):
  the target (known before the trial) smoothed without phase lag, its exact inverse
  through the twin's second-order model as feedforward, advanced by the twin's dead time
  and the hold's half update; a Smith
  predictor (the twin's model run inside the controller, its delayed output compared with
  the measured force, so the feedback sees the undelayed model plus the mismatch); a PI
  on that error with anti-windup (conditional integration: the integrator holds while
  the command is saturated in the direction the error pushes).
* :class:`PIDController`: a PID (derivative on the measurement, first-order filtered,
  the same anti-windup) around rE = 0.5, whose gains come from :func:`relay_tuning`
  (Astrom & Hagglund 1984, "Automatic tuning of simple regulators with specifications on
  phase and amplitude margins", Automatica 20:645; Ziegler-Nichols ultimate-point rules):
  no twin is used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nmsid.analysis.control.errors import ControlDesignError
from nmsid.analysis.control.plant import SecondOrderPlant

V_MIN, V_MAX = -0.5, 0.5
"""v = rE - 0.5 stays within rE in [0, 1]."""


def smoothed_target(target_N: np.ndarray, Ts_s: float, sigma_s: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The target smoothed by a centred Gaussian (zero phase: the target is known ahead)
    and its first two derivatives, at the update grid.

    A step becomes an S-curve centred on the step, so its inverse through the model is
    finite; a 2 Hz sine loses ``1 - exp(-(2 pi 2 sigma)^2 / 2)`` of its amplitude (0.2 %
    at sigma = 5 ms, 1.8 % at 15 ms).
    """
    r = np.asarray(target_N, dtype=float)
    if r.size < 3:
        z = np.zeros(r.size)
        return r.copy(), z, z
    k = max(1, math.ceil(4 * sigma_s / Ts_s))
    x = np.arange(-k, k + 1) * Ts_s
    w = np.exp(-0.5 * (x / max(sigma_s, 1e-9)) ** 2)
    w /= w.sum()
    padded = np.concatenate([np.full(k, r[0]), r, np.full(k, r[-1])])
    rs = np.convolve(padded, w, mode="valid")
    dr = np.gradient(rs, Ts_s)
    ddr = np.gradient(dr, Ts_s)
    return rs, dr, ddr


@dataclass
class TwinControllerSettings:
    """What ``controller.json`` fixes for the twin-based controller."""

    plant: SecondOrderPlant
    Kc: float
    """Proportional gain, unit rE per N."""
    Ti_s: float
    smoothing_s: float
    """Gaussian smoothing of the target before its inversion (how fast the feedforward
    asks the muscle to go; a step becomes an S-curve of about 4 sigma)."""
    learning_gain: float = 0.0
    """Trial-to-trial learning (0: off): the feedforward of a repeated target is corrected
    by this fraction of the previous trial's error, through the model's static gain."""


class TwinController:
    """Feedforward inverse + Smith predictor + PI with anti-windup (see the module)."""

    name = "twin"

    def __init__(self, settings: TwinControllerSettings, Ts_s: float, queue: int):
        self.s = settings
        self.Ts_s = float(Ts_s)
        self.queue = int(queue)
        self.Ad, self.Bd, self.C = settings.plant.zoh(self.Ts_s)
        # the 2 x 2 model as floats (the step runs once per update, in the loop)
        self._a = tuple(float(v) for v in self.Ad.ravel())
        self._b = (float(self.Bd[0]), float(self.Bd[1]))
        self.nL = settings.plant.delay_samples(self.Ts_s)
        self._learned: dict[str, np.ndarray] = {}

    def start(self, target_N: np.ndarray, target_id: str = "") -> np.ndarray:
        """Prepare a trial; return the updates to queue before the start (``queue`` of
        them), rE."""
        p = self.s.plant
        M = len(target_N)
        self.target = np.asarray(target_N, dtype=float)
        self.target_id = target_id
        r, dr, ddr = smoothed_target(self.target, self.Ts_s, self.s.smoothing_s)
        y_des = r - p.offset_N
        wn, z = p.wn_rad_s, p.zeta
        ff_grid = (ddr + 2 * z * wn * dr + wn * wn * y_des) / (p.Kp * wn * wn)
        t_grid = np.arange(M) * self.Ts_s
        # the hold's mid-point, advanced by the twin's dead time
        t_ff = t_grid + 0.5 * self.Ts_s + p.L_s
        self.v_ff = np.interp(t_ff, t_grid, ff_grid)
        learned = self._learned.get(target_id) if target_id else None
        if learned is not None and learned.size == M:
            self.v_ff = self.v_ff + learned
        self.y_des_at = np.interp(t_grid + p.L_s, t_grid, y_des)   # wanted y at m Ts + L
        self.x1 = self.x2 = 0.0
        self.yhat0 = np.zeros(M + self.queue + 2)   # model output at the start of update m
        self.v = np.zeros(M + self.queue + 1)
        self.I = 0.0
        self.errors = np.zeros(M)
        first = []
        for m in range(min(self.queue, M)):
            first.append(self._apply(m, self.v_ff[m]))
        return np.array(first)

    def _apply(self, m: int, v_unsat: float) -> float:
        v = min(max(float(v_unsat), V_MIN), V_MAX)
        a11, a12, a21, a22 = self._a
        b1, b2 = self._b
        self.v[m] = v
        self.yhat0[m] = self.x1
        self.x1, self.x2 = (a11 * self.x1 + a12 * self.x2 + b1 * v,
                            a21 * self.x1 + a22 * self.x2 + b2 * v)
        self.yhat0[m + 1] = self.x1
        return v + 0.5

    def step(self, j: int, y_mean_N: float) -> float:
        """The force of update ``j`` was read (its mean): rE of update ``j + queue``."""
        p = self.s.plant
        m = j + self.queue
        if m >= len(self.v_ff):
            return 0.5
        # the model's output over update j, delayed as the force is (mean of its ends)
        a, b = j - self.nL, j + 1 - self.nL
        y_model_delayed = 0.5 * ((self.yhat0[a] if a >= 0 else 0.0)
                                 + (self.yhat0[b] if b >= 0 else 0.0))
        mismatch = (y_mean_N - p.offset_N) - y_model_delayed
        # y at the end of update m (+ L) if it were the feedforward alone, as known now
        a11, a12, _, _ = self._a
        predicted = (a11 * self.x1 + a12 * self.x2 + self._b[0] * self.v_ff[m]) + mismatch
        e = self.y_des_at[min(m + 1, len(self.y_des_at) - 1)] - predicted
        self.errors[j] = e
        v_unsat = self.v_ff[m] + self.s.Kc * e + self.I
        sat_hi, sat_lo = v_unsat > V_MAX, v_unsat < V_MIN
        if not ((sat_hi and e > 0) or (sat_lo and e < 0)):   # anti-windup
            self.I += self.s.Kc * self.Ts_s / self.s.Ti_s * e
        return self._apply(m, self.v_ff[m] + self.s.Kc * e + self.I)

    def finish(self, achieved_mean_N: np.ndarray) -> None:
        """After a completed trial: learn from its error (when learning is on)."""
        g = self.s.learning_gain
        if g <= 0 or not self.target_id:
            return
        M = len(self.target)
        err = np.zeros(M)
        n = min(M, len(achieved_mean_N))
        err[:n] = self.target[:n] - np.asarray(achieved_mean_N[:n])
        shift = self.nL + self.queue
        corr = np.zeros(M)
        corr[:M - shift] = err[shift:] / self.s.plant.Kp
        prev = self._learned.get(self.target_id, np.zeros(M))
        self._learned[self.target_id] = prev + g * corr


@dataclass(frozen=True)
class PIDGains:
    """A PID in parallel form on the force error, output in rE units."""

    Kc: float
    """Unit rE per N."""
    Ti_s: float
    Td_s: float
    rule: str = ""
    ultimate_gain: float = math.nan
    ultimate_period_s: float = math.nan

    def to_dict(self) -> dict:
        return {"Kc": self.Kc, "Ti_s": self.Ti_s, "Td_s": self.Td_s, "rule": self.rule,
                "ultimate_gain": self.ultimate_gain,
                "ultimate_period_s": self.ultimate_period_s}


class PIDController:
    """The twin-free baseline: PID around rE = 0.5 (see the module)."""

    name = "baseline"

    def __init__(self, gains: PIDGains, Ts_s: float, queue: int, derivative_N: float = 10.0):
        self.g = gains
        self.Ts_s = float(Ts_s)
        self.queue = int(queue)
        self.Tf_s = gains.Td_s / derivative_N if gains.Td_s > 0 else 0.0

    def start(self, target_N: np.ndarray, target_id: str = "") -> np.ndarray:
        self.target = np.asarray(target_N, dtype=float)
        self.I = 0.0
        self.D = 0.0
        self.y_prev: float | None = None
        return np.full(min(self.queue, len(self.target)), 0.5)

    def step(self, j: int, y_mean_N: float) -> float:
        m = j + self.queue
        if m >= len(self.target):
            return 0.5
        g = self.g
        # the error now against the target the decided update will meet
        e = self.target[min(j + 1, len(self.target) - 1)] - y_mean_N
        if g.Td_s > 0 and self.y_prev is not None:
            a = self.Tf_s / (self.Tf_s + self.Ts_s)
            self.D = a * self.D - g.Kc * g.Td_s * (1 - a) * (y_mean_N - self.y_prev) / self.Ts_s
        self.y_prev = y_mean_N
        v_unsat = g.Kc * e + self.I + self.D
        sat_hi, sat_lo = v_unsat > V_MAX, v_unsat < V_MIN
        if not ((sat_hi and e > 0) or (sat_lo and e < 0)):
            self.I += g.Kc * self.Ts_s / g.Ti_s * e
        v = min(max(g.Kc * e + self.I + self.D, V_MIN), V_MAX)
        return v + 0.5

    def finish(self, achieved_mean_N: np.ndarray) -> None:
        """No learning in the baseline."""


# -- relay auto-tuning ------------------------------------------------------------------
@dataclass(frozen=True)
class RelayResult:
    """What the relay experiment found."""

    amplitude_N: float
    """Half peak-to-peak of the force oscillation (hysteresis removed)."""
    period_s: float
    ultimate_gain: float
    """Ku = 4 d / (pi sqrt(a^2 - eps^2)), unit rE per N."""
    n_periods: int


class RelayExperiment:
    """Relay feedback around a force level (Astrom & Hagglund 1984): rE = 0.5 + d sign(e)
    with hysteresis ``eps_N``; same step interface as the controllers."""

    name = "relay"

    def __init__(self, d: float, eps_N: float, Ts_s: float, queue: int):
        if not 0 < d <= 0.5:
            raise ControlDesignError(f"relay amplitude {d!r} must be in (0, 0.5] (rE units)")
        self.d = float(d)
        self.eps_N = float(eps_N)
        self.Ts_s = float(Ts_s)
        self.queue = int(queue)

    def start(self, target_N: np.ndarray, target_id: str = "") -> np.ndarray:
        self.target = np.asarray(target_N, dtype=float)
        self.u = 0.5 + self.d
        self.outputs: list[float] = []
        return np.full(min(self.queue, len(self.target)), self.u)

    def step(self, j: int, y_mean_N: float) -> float:
        e = self.target[min(j, len(self.target) - 1)] - y_mean_N
        if e > self.eps_N:
            self.u = 0.5 + self.d
        elif e < -self.eps_N:
            self.u = 0.5 - self.d
        self.outputs.append(self.u)
        return self.u

    def finish(self, achieved_mean_N: np.ndarray) -> None:
        """Nothing to learn."""


def relay_analysis(force_mean_N: np.ndarray, Ts_s: float, d: float, eps_N: float,
                   settle_s: float = 1.0) -> RelayResult:
    """Amplitude and period of the relay oscillation (after ``settle_s``), and Ku.

    Raises
    ------
    ControlDesignError
        If the force did not oscillate (fewer than 2 full periods).
    """
    y = np.asarray(force_mean_N, dtype=float)[round(settle_s / Ts_s):]
    if y.size < 8:
        raise ControlDesignError("the relay experiment is too short to find an oscillation")
    yc = y - np.mean(y)
    ups = np.flatnonzero((yc[:-1] < 0) & (yc[1:] >= 0))
    if ups.size < 3:
        raise ControlDesignError(f"the force did not oscillate under relay feedback "
                                 f"({max(ups.size - 1, 0)} periods); no baseline tuning")
    # sub-sample crossing times
    t_up = ups + (-yc[ups]) / (yc[ups + 1] - yc[ups])
    period_s = float(np.mean(np.diff(t_up))) * Ts_s
    seg = y[ups[0]:ups[-1]]
    a = 0.5 * (float(seg.max()) - float(seg.min()))
    a_eff = math.sqrt(max(a * a - eps_N * eps_N, (0.1 * a) ** 2))
    Ku = 4.0 * d / (math.pi * a_eff)
    return RelayResult(a, period_s, Ku, int(ups.size - 1))


def ziegler_nichols_pid(relay: RelayResult) -> PIDGains:
    """The Ziegler-Nichols ultimate-point PID: Kc = 0.6 Ku, Ti = Tu / 2, Td = Tu / 8."""
    Ku, Tu = relay.ultimate_gain, relay.period_s
    return PIDGains(0.6 * Ku, 0.5 * Tu, 0.125 * Tu, "Ziegler-Nichols PID from relay "
                    "feedback (Astrom-Hagglund)", Ku, Tu)
