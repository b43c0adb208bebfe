"""``nmsid control design``: a force controller derived from the twin.

For the operating sE (default: where the twin's wn is highest within its tested range,
the fastest muscle response; ``sE=`` to choose) the twin's second-order model with its dead
time gives the plant; the controller (:class:`~nmsid.analysis.control.controllers.
TwinController`) inverts it as feedforward and closes a Smith-predictor PI loop tuned by
the lambda rule for a second-order plant: ``Ti = 2 zeta / wn``, ``Kc = Ti / (Kp lambda)``,
so the nominal loop is ``~ 1 / (lambda s)`` below wn; ``lambda`` at least four times the
loop's delay (queue of updates + dead time) and 80 ms. The same design is evaluated at
every sE of the twin's range: stability margins of the implemented loop (Smith predictor
and delays included) and of the nominal loop, and the tracking predicted on the default
targets by simulating the twin in closed loop.

Limits from the calibration: rE in [0, 1] at the operating sE, so the currents stay within
``Imin + sE (Imax - Imin)`` per muscle (never above Imax for sE <= 1); the session's own
ceilings and the device's range apply on top (``rig.tracking``).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nmsid.analysis.control.controllers import (
    V_MAX,
    V_MIN,
    TwinController,
    TwinControllerSettings,
)
from nmsid.analysis.control.errors import ControlDesignError, ControllerFileError
from nmsid.analysis.control.margins import Margins, stability_margins
from nmsid.analysis.control.plant import SecondOrderPlant
from nmsid.analysis.control.targets import RANGE_FRACTION, Target, default_targets
from nmsid.protocols.joints import QUANTITY_UNITS
from nmsid.protocols.reprs import html_repr, number_span, short_repr, to_dataframe

FORMAT = "nmsid-controller"
FORMAT_VERSION = 1
UPDATE_HZ = 200.0
"""Default stream update rate (5 ms: 5 carrier periods at 1 kHz, 10 samples at 2 kHz)."""
QUEUE_UPDATES = 2
"""Updates queued ahead of the output: the one playing and the next (a decision is never
late on a real device); the loop's delay is about ``QUEUE_UPDATES - 1`` updates plus a
hold."""
LAMBDA_MIN_S = 0.08
LAMBDA_DELAY_FACTOR = 4.0
N_LEVELS = 15
SMOOTHING_WN = 0.5
"""Gaussian smoothing of the target, sigma = SMOOTHING_WN / wn: the steepest the twin's
feedforward asks for without saturating rE on the default steps."""


@dataclass
class LevelDesign:
    """The design evaluated at one sE."""

    sE: float
    Kp: float
    wn_rad_s: float
    zeta: float
    Kc: float
    Ti_s: float
    margins: dict
    """Implemented loop (Smith predictor, delays) at the plant input."""
    nominal_margins: dict
    """``C G0`` (the loop the Smith predictor leaves when the model is exact)."""
    predicted_rmse_pct: dict
    """Per default target: RMSE in % of its range, twin simulated in closed loop."""

    def __repr__(self) -> str:
        gm = self.margins.get("gain_margin")
        pm = self.margins.get("phase_margin_deg")
        return short_repr("LevelDesign", f"sE {self.sE:g}", f"Kc {self.Kc:.4g} rE/N",
                          f"Ti {1000 * self.Ti_s:.1f} ms",
                          f"GM {'inf' if gm is None else format(gm, '.2f')}",
                          f"PM {'n/a' if pm is None else format(pm, '.1f')} deg",
                          f"RMSE {number_span(self.predicted_rmse_pct.values(), '.2g')} % "
                          "of range" if self.predicted_rmse_pct else "")

    _repr_html_ = html_repr


@dataclass
class ControllerDesign:
    """What ``controller.json`` holds."""

    participant: str
    sE: float
    plant: dict
    Kc: float
    Ti_s: float
    smoothing_s: float
    update_Hz: float
    queue: int
    learning_gain: float
    calibration: dict
    force_range_N: tuple[float, float]
    twin_source: list = field(default_factory=list)
    unmodelled_effects: list = field(default_factory=list)
    levels: list[LevelDesign] = field(default_factory=list)
    baseline: dict = field(default_factory=dict)
    joint: str = "elbow"
    """The twin's joint (``docs/joints.md``); optional in the file (absent: the elbow)."""
    measured_unit: str = "N"
    """``N`` or ``N m``: the unit of Kp, the offset, the targets (``force_range_N``) and
    the error; ``Kc`` is rE per this unit."""

    @property
    def per_unit(self) -> str:
        """``rE/N`` or ``rE/(N m)``."""
        return "rE/" + (self.measured_unit if " " not in self.measured_unit
                        else f"({self.measured_unit})")

    # -- runtime ------------------------------------------------------------------------
    @property
    def plant_model(self) -> SecondOrderPlant:
        return SecondOrderPlant(**self.plant)

    def make_controller(self, update_Hz: float | None = None) -> TwinController:
        Ts = 1.0 / (update_Hz or self.update_Hz)
        return TwinController(TwinControllerSettings(
            self.plant_model, self.Kc, self.Ti_s, self.smoothing_s, self.learning_gain),
            Ts, self.queue)

    def targets(self) -> list[Target]:
        return default_targets(*self.force_range_N)

    def rows(self) -> list[dict]:
        """One dict per evaluated sE: the plant, the PI and its margins, and the predicted
        RMSE (% of range) on each default target."""
        return [{"sE": lv.sE, "Kp": lv.Kp, "wn_rad_s": lv.wn_rad_s, "zeta": lv.zeta,
                 "Kc": lv.Kc, "Ti_s": lv.Ti_s, "gain_margin": lv.margins.get("gain_margin"),
                 "phase_margin_deg": lv.margins.get("phase_margin_deg"),
                 **{f"rmse_pct_{k}": v for k, v in lv.predicted_rmse_pct.items()}}
                for lv in self.levels]

    def to_dataframe(self):
        """:meth:`rows` as a ``pandas.DataFrame`` (needs pandas)."""
        return to_dataframe(self.rows())

    def __repr__(self) -> str:
        return short_repr("ControllerDesign", self.participant or "participant",
                          f"sE {self.sE:g}", f"Kc {self.Kc:.4g} {self.per_unit}",
                          f"Ti {1000 * self.Ti_s:.1f} ms", f"update {self.update_Hz:g} Hz",
                          f"targets {self.force_range_N[0]:.2f}-{self.force_range_N[1]:.2f} "
                          f"{self.measured_unit}",
                          f"{len(self.levels)} sE levels evaluated" if self.levels else "",
                          "unmodelled effects " + ", ".join(map(str, self.unmodelled_effects))
                          if self.unmodelled_effects else "")

    _repr_html_ = html_repr

    def current_limits_mA(self, calibration) -> tuple[float, float]:
        """Largest current per channel at rE in [0, 1] and this sE, for ``calibration``
        (any object with the four currents)."""
        c = calibration
        return (float(c.Iemin_mA) + self.sE * (float(c.Iemax_mA) - float(c.Iemin_mA)),
                float(c.Ifmin_mA) + self.sE * (float(c.Ifmax_mA) - float(c.Ifmin_mA)))

    # -- file ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        d["force_range_N"] = list(self.force_range_N)
        if (self.joint, self.measured_unit) == ("elbow", "N"):   # optional: the file of before
            del d["joint"], d["measured_unit"]
        return {"format": FORMAT, "format_version": FORMAT_VERSION, **d}

    def save(self, path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False,
                                         default=_json_num) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path) -> ControllerDesign:
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ControllerFileError(f"{p}: no such controller file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ControllerFileError(f"{p}: not a readable controller.json ({exc})") from None
        return cls.from_dict(d, p)

    @classmethod
    def from_dict(cls, d, where="<controller>") -> ControllerDesign:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ControllerFileError(f"{where}: format must be {FORMAT!r} (a file written by "
                                      "nmsid control design)")
        if d.get("format_version") != FORMAT_VERSION:
            raise ControllerFileError(f"{where}: format_version {d.get('format_version')!r}; "
                                      f"this reader knows {FORMAT_VERSION}")
        try:
            plant = {k: float(d["plant"][k]) for k in ("Kp", "wn_rad_s", "zeta", "offset_N",
                                                         "L_s")}
            out = cls(participant=str(d.get("participant", "")), sE=float(d["sE"]),
                      plant=plant, Kc=float(d["Kc"]), Ti_s=float(d["Ti_s"]),
                      smoothing_s=float(d["smoothing_s"]), update_Hz=float(d["update_Hz"]),
                      queue=int(d["queue"]), learning_gain=float(d.get("learning_gain", 0.0)),
                      calibration=dict(d.get("calibration") or {}),
                      force_range_N=(float(d["force_range_N"][0]),
                                     float(d["force_range_N"][1])),
                      twin_source=list(d.get("twin_source") or []),
                      unmodelled_effects=list(d.get("unmodelled_effects") or []),
                      baseline=dict(d.get("baseline") or {}),
                      joint=str(d.get("joint", "elbow")),
                      measured_unit=str(d.get("measured_unit", "N")))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ControllerFileError(f"{where}: item {exc} is missing or not a number") from None
        checks = (("sE", out.sE, 0, 2), ("plant.Kp", plant["Kp"], 0, 1e4),
                  ("plant.wn_rad_s", plant["wn_rad_s"], 0, 1e4),
                  ("plant.zeta", plant["zeta"], 0, 100),
                  ("Kc", out.Kc, -1e-12, 1e3), ("Ti_s", out.Ti_s, 0, 1e3),
                  ("smoothing_s", out.smoothing_s, 0, 10), ("update_Hz", out.update_Hz, 1, 5000),
                  ("queue", out.queue, 0, 100), ("learning_gain", out.learning_gain, -1e-12, 1))
        for name, v, lo, hi in checks:
            if not (math.isfinite(v) and lo < v <= hi):
                raise ControllerFileError(f"{where}: {name} = {v!r} is outside ({lo:g}, {hi:g}]")
        if not plant["L_s"] >= 0:
            raise ControllerFileError(f"{where}: plant.L_s must be >= 0")
        if out.measured_unit not in QUANTITY_UNITS.values() or not re.fullmatch(
                r"[a-z][a-z0-9_]{0,31}", out.joint):
            raise ControllerFileError(f"{where}: joint {out.joint!r} / measured_unit "
                                      f"{out.measured_unit!r}: expected a joint name and one of "
                                      + ", ".join(repr(u) for u in QUANTITY_UNITS.values()))
        return out


def _json_num(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(f"{type(x).__name__} is not JSON")


# -- design -------------------------------------------------------------------------------
def loop_responses(plant: SecondOrderPlant, Kc: float, Ti_s: float, delay_s: float):
    """(implemented loop, nominal loop) as functions of w: the Smith predictor's loop at
    the plant input ``C' G e^{-sD}``, ``C' = C / (1 + C G0 (1 - e^{-sD}))``, and ``C G0``.
    ``D`` is the whole loop delay (dead time + the stream's)."""
    def C(s):
        return Kc * (1.0 + 1.0 / (Ti_s * s))

    def G0(s):
        return plant.Kp * plant.wn_rad_s ** 2 / (s * s + 2 * plant.zeta * plant.wn_rad_s * s
                                                 + plant.wn_rad_s ** 2)

    def implemented(w):
        s = 1j * np.asarray(w, dtype=float)
        d = np.exp(-s * delay_s)
        c = C(s)
        return c / (1.0 + c * G0(s) * (1.0 - d)) * G0(s) * d

    def nominal(w):
        s = 1j * np.asarray(w, dtype=float)
        return C(s) * G0(s)

    return implemented, nominal


def pi_tuning(plant: SecondOrderPlant, delay_s: float, lambda_s: float | None = None
              ) -> tuple[float, float, float]:
    """(Kc, Ti_s, lambda_s) of the lambda rule for a second-order plant."""
    lam = lambda_s if lambda_s is not None else max(LAMBDA_MIN_S, LAMBDA_DELAY_FACTOR * delay_s)
    Ti = 2.0 * plant.zeta / plant.wn_rad_s
    return Ti / (plant.Kp * lam), Ti, lam


def simulate_tracking(controller, plant: SecondOrderPlant, target: np.ndarray, Ts_s: float,
                      sub: int = 5, target_id: str = "") -> np.ndarray:
    """The twin in closed loop with ``controller`` on ``target`` (held per update): the
    mean force over each update. The plant is integrated exactly (ZOH) on ``sub`` steps
    per update, delayed by its dead time; the controller's queue as on the rig."""
    M = len(target)
    h = Ts_s / sub
    Ad, Bd, _ = plant.zoh(h)
    a11, a12, a21, a22 = (float(v) for v in Ad.ravel())
    b1, b2 = float(Bd[0]), float(Bd[1])
    nL = round(plant.L_s / h)
    queue = controller.queue
    v = [0.0] * (M + queue + 1)
    first = controller.start(np.asarray(target, dtype=float), target_id)
    for i, u in enumerate(first):
        v[i] = float(u) - 0.5
    hist = [0.0] * (nL + 1)      # ring buffer of fine-step inputs for the dead time
    pos = 0
    x1 = x2 = 0.0
    means = np.empty(M)
    off = plant.offset_N
    for j in range(M):
        acc = 0.0
        vj = v[j]
        for _ in range(sub):
            hist[pos] = vj
            u = hist[(pos - nL) % (nL + 1)]
            pos = (pos + 1) % (nL + 1)
            x1, x2 = a11 * x1 + a12 * x2 + b1 * u, a21 * x1 + a22 * x2 + b2 * u
            acc += x1
        means[j] = off + acc / sub
        if j + queue < len(v):
            v[j + queue] = controller.step(j, float(means[j])) - 0.5
    return means


def rmse_pct_of_range(achieved: np.ndarray, target: np.ndarray, skip: int = 0) -> float:
    """RMSE of ``achieved - target`` (after ``skip`` samples) in % of the target's range."""
    a, t = np.asarray(achieved)[skip:], np.asarray(target)[skip:]
    span = float(np.max(target) - np.min(target)) or 1.0
    return float(100.0 * np.sqrt(np.mean((a - t) ** 2)) / span)


def _effects(twin) -> tuple[float, list]:
    L = 0.0
    other = []
    for e in twin.effects or []:
        if e.get("name") == "dead_time":
            L = float((e.get("params") or {}).get("L_s", 0.0))
        else:
            other.append(e.get("name"))
    if twin.muscle_model is not None:
        other.append("muscle_model (the controller uses the second-order form)")
    return L, other


def plant_at(twin, sE: float) -> SecondOrderPlant:
    Kp, wn, z = (float(x) for x in twin.parameters_at(sE))
    L, _ = _effects(twin)
    if not (Kp > 0 and wn > 0 and z > 0):
        raise ControlDesignError(f"twin of {twin.participant}: at sE = {sE:g} Kp = {Kp:.3g}, "
                                 f"wn = {wn:.3g}, zeta = {z:.3g}; a controller needs all > 0")
    return SecondOrderPlant(Kp, wn, z, float(twin.offset_N(np.clip(sE, *twin.sE_range))), L)


def design_controller(twin, *, sE: float | None = None, update_Hz: float = UPDATE_HZ,
                      queue: int = QUEUE_UPDATES, lambda_s: float | None = None,
                      learning_gain: float = 0.0, levels: int = N_LEVELS) -> ControllerDesign:
    """Design the twin-based controller and evaluate it over the twin's sE range.

    Parameters
    ----------
    twin : nmsid.analysis.twin.Twin
    sE : float, optional
        Operating co-activation; default where wn peaks within ``twin.sE_range``.
    update_Hz : float
        Stream update rate.
    queue : int
        Updates queued ahead of the output.
    lambda_s : float, optional
        Closed-loop time constant of the PI (default from the loop delay).
    learning_gain : float
        Trial-to-trial learning (0: off, at most 1).

    Raises
    ------
    ControlDesignError
        A setting outside its range, or a twin without positive parameters there.
    """
    lo, hi = twin.sE_range
    if not (math.isfinite(update_Hz) and 10.0 <= update_Hz <= 2000.0):
        raise ControlDesignError(f"update rate {update_Hz!r} Hz must be within 10-2000 Hz")
    if not 1 <= queue <= 20:
        raise ControlDesignError(f"queue {queue!r} must be 1-20 updates")
    if not 0.0 <= learning_gain <= 1.0:
        raise ControlDesignError(f"learning gain {learning_gain!r} must be within [0, 1]")
    if lambda_s is not None and not (math.isfinite(lambda_s) and 0.005 <= lambda_s <= 5.0):
        raise ControlDesignError(f"lambda {lambda_s!r} s must be within 0.005-5 s")
    grid = np.linspace(lo, hi, max(2, int(levels))) if hi > lo else np.array([lo])
    if sE is None:   # the fastest response among the levels that keep currents <= Imax
        usable = grid[grid <= 1.0]
        if usable.size == 0:
            raise ControlDesignError(f"the twin's tested range {lo:g}-{hi:g} lies above sE = 1 "
                                     "(a muscle would exceed its Imax); give --sE <= 1")
        wn = np.array([float(twin.parameters_at(s)[1]) for s in usable])
        sE = float(usable[int(np.argmax(wn))])
    elif not (math.isfinite(sE) and lo <= sE <= hi):
        raise ControlDesignError(f"sE {sE!r} is outside the twin's tested range "
                                 f"{lo:g}-{hi:g}")
    if sE > 1.0:
        raise ControlDesignError(f"sE {sE:g} > 1 would drive a muscle above its Imax at rE = 0 "
                                 "or 1; choose sE <= 1")
    Ts = 1.0 / update_Hz
    L, unmodelled = _effects(twin)
    delay = L + (queue - 0.5) * Ts
    plant = plant_at(twin, sE)
    Kc, Ti, lam = pi_tuning(plant, delay, lambda_s)
    smoothing = SMOOTHING_WN / plant.wn_rad_s
    f_lo, f_hi = plant.force_span_N
    mid, half = 0.5 * (f_lo + f_hi), 0.5 * RANGE_FRACTION * (f_hi - f_lo)
    design = ControllerDesign(
        participant=twin.participant, sE=float(sE), plant=asdict(plant), Kc=Kc, Ti_s=Ti,
        smoothing_s=smoothing, update_Hz=float(update_Hz), queue=int(queue),
        learning_gain=float(learning_gain), calibration=dict(twin.calibration),
        force_range_N=(mid - half, mid + half), twin_source=list(twin.source),
        unmodelled_effects=unmodelled,
        joint=str(getattr(twin, "joint", "elbow")),
        measured_unit=str(getattr(twin, "measured_unit", "N")),
        baseline={"rule": "Ziegler-Nichols PID from relay feedback (Astrom-Hagglund), "
                          "tuned in the tracking session without the twin",
                  "relay_amplitude_rE": 0.15, "relay_hysteresis_N": 0.05,
                  "relay_s": 6.0, "lambda_s": lam})
    for s in grid:
        p = plant_at(twin, float(s))
        kc, ti, _ = pi_tuning(p, delay, lambda_s)
        impl, nom = loop_responses(p, kc, ti, delay)
        m_impl, m_nom = stability_margins(impl), stability_margins(nom)
        ctrl = TwinController(TwinControllerSettings(p, kc, ti, SMOOTHING_WN / p.wn_rad_s), Ts,
                              queue)
        span = p.force_span_N
        mid_s, half_s = 0.5 * (span[0] + span[1]), 0.5 * RANGE_FRACTION * (span[1] - span[0])
        pred = {}
        for t in default_targets(mid_s - half_s, mid_s + half_s):
            r = t.samples(update_Hz)
            y = simulate_tracking(ctrl, p, r, Ts)
            pred[t.name] = round(rmse_pct_of_range(y, r, int(t.lead_s * update_Hz)), 3)
        design.levels.append(LevelDesign(float(s), p.Kp, p.wn_rad_s, p.zeta, kc, ti,
                                         m_impl.to_dict(), m_nom.to_dict(), pred))
    return design


def design_report(design: ControllerDesign) -> str:
    """The design report (Markdown)."""
    p = design.plant
    u = design.measured_unit
    lines = [f"# Controller design: {design.participant or 'participant'}"
             + ("" if design.joint == "elbow" else f" ({design.joint}, {u})"), "",
             (f"Operating sE {design.sE:.3f}: Kp {p['Kp']:.3f} {u}, wn {p['wn_rad_s']:.2f} "
             f"rad/s, zeta {p['zeta']:.3f}, offset {p['offset_N']:.3f} {u}, dead time "
             f"{1000 * p['L_s']:.1f} ms."),
             f"Stream: {design.update_Hz:g} Hz updates, {design.queue} queued ahead.",
             (f"PI (Smith predictor, anti-windup): Kc {design.Kc:.4g} {design.per_unit}, Ti "
             f"{design.Ti_s * 1000:.1f} ms; feedforward: the twin inverted on the target "
             f"smoothed over {design.smoothing_s * 1000:.1f} ms (sigma); trial-to-trial "
             f"learning gain {design.learning_gain:g}."),
             (f"Default targets within {design.force_range_N[0]:.2f} .. "
             f"{design.force_range_N[1]:.2f} {u} ({RANGE_FRACTION:.0%} of the twin's range at "
             "this sE)."),
             (f"Limits: rE in [0, 1] at sE {design.sE:.3f}: at most Imin + "
             f"{design.sE:.3f} (Imax - Imin) per muscle, and the session's ceilings."),
             ""]
    if design.unmodelled_effects:
        lines += ["Not modelled by the controller (the feedback has to absorb them): "
                  + ", ".join(design.unmodelled_effects), ""]
    names = list(design.levels[0].predicted_rmse_pct) if design.levels else []
    lines += ["## Per sE: margins and predicted tracking (twin in closed loop)", "",
              "| sE | Kp | wn | zeta | Kc | Ti ms | GM | PM deg | delay margin ms | "
              + " | ".join(f"{n} RMSE %" for n in names) + " |",
              "|" + "---|" * (9 + len(names))]
    for lv in design.levels:
        m = lv.margins
        gm = "inf" if m["gain_margin"] is None else f"{m['gain_margin']:.2f}"
        pm = "-" if m["phase_margin_deg"] is None else f"{m['phase_margin_deg']:.1f}"
        dm = "-" if m["delay_margin_s"] is None else f"{1000 * m['delay_margin_s']:.1f}"
        lines.append(f"| {lv.sE:.3f} | {lv.Kp:.3f} | {lv.wn_rad_s:.2f} | {lv.zeta:.3f} | "
                     f"{lv.Kc:.4g} | {lv.Ti_s * 1000:.1f} | {gm} | {pm} | {dm} | "
                     + " | ".join(f"{lv.predicted_rmse_pct[n]:.2f}" for n in names) + " |")
    lines += ["", ("Margins are those of the implemented loop at the plant input (the Smith "
              "predictor with the twin's dead time and the stream's delay). Predicted RMSE "
              "assumes the participant is the twin; the tracking session measures the truth."),
              ""]
    return "\n".join(lines)


__all__ = [
    "V_MAX",
    "V_MIN",
    "ControllerDesign",
    "LevelDesign",
    "Margins",
    "design_controller",
    "design_report",
    "loop_responses",
    "pi_tuning",
    "rmse_pct_of_range",
    "simulate_tracking",
]
