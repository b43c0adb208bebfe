"""The augmented model as a twin file (``docs/twin-file.md``) that ``sim_backends`` runs.

The per-sE parameters of the final fit (on all trials) become curves of sE (linear,
quadratic or exponential, lowest AICc, as the identification does), and the winning
effect(s) are translated from this package's own parameterisation to the simulator's names:

- ``dead_time``: ``L_s``; ``activation_dynamics``: ``tau_s``;
- ``fatigue``: our constant loss rate ``lambda`` becomes ``shape = exponential``,
  ``gain_loss_pct = 100 (1 - exp(-lambda c_ref))`` with ``reference_stim_s = c_ref`` (675 s);
- ``flexor_extensor_asymmetry``: ``wn_ratio``, ``zeta_ratio`` (orientation convention:
  see :func:`canonical_asymmetry`);
- ``recruitment_nonlinearity``: our knot curve is projected onto the closest of the
  simulator's documented shapes (power, sigmoid, threshold_saturation) by least squares on
  the net static map over the tested sE range (what the data constrain);
- ``baseline_drift``: ``amplitude_N`` (RMS of the fitted slow baseline) and ``corner_Hz``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import optimize

from nmsid.analysis.curves import fit_curve
from nmsid.analysis.gap.effects import Effect
from nmsid.analysis.gap.models import REFERENCE_STIM_S
from nmsid.sim_backends.effects import RecruitmentNonlinearity


def fatigue_loss_pct(rate_per_s: float, reference_stim_s: float = REFERENCE_STIM_S) -> float:
    """Gain lost over ``reference_stim_s`` of stimulation at a constant relative rate."""
    return 100.0 * (1.0 - math.exp(-rate_per_s * reference_stim_s))


def net_static_map(h, sE_levels, n_d: int = 41) -> np.ndarray:
    """(n_levels, n_d) normalised net drive ``(h(I_e) - h(I_f)) / (2 sE)`` over
    ``d = rE - 0.5`` in [-0.5, 0.5], each row scaled to unit least-squares slope (the
    per-sE gain is free, so only the shape is identifiable)."""
    d = np.linspace(-0.5, 0.5, n_d)
    rows = []
    for sE in np.atleast_1d(sE_levels):
        x = (h((0.5 + d) * sE) - h((0.5 - d) * sE)) / (2 * sE)
        slope = float(x @ d / (d @ d))
        rows.append(x / slope if slope != 0 else x)
    return np.array(rows)


def nonlinearity_index_pct(h, sE_levels) -> float:
    """RMS departure of the normalised net static map from a straight line, in % of the
    drive's range (0 for linear recruitment): the recruitment effect's size that a chirp
    at constant sE can see, independent of the curve's family."""
    m = net_static_map(h, sE_levels)
    d = np.linspace(-0.5, 0.5, m.shape[1])
    return float(100.0 * np.sqrt(np.mean((m - d[None, :]) ** 2)))


def _sim_h(params: dict):
    """The simulator's documented recruitment curve for ``params`` (used only to write the
    twin file in the simulator's own terms)."""
    return RecruitmentNonlinearity(**params).h


def project_recruitment(h, sE_levels) -> dict:
    """The simulator-shape parameters whose net static map is closest to our curve ``h``."""
    target = net_static_map(h, sE_levels)
    best, best_cost = None, np.inf
    trials = [
        ("power", ["gamma"], [[0.5], [1.5], [2.5], [3.5]], [(0.1, 10.0)]),
        ("sigmoid", ["slope", "midpoint"], [[4, 0.5], [8, 0.4], [12, 0.6], [6, 0.3]],
         [(0.5, 100.0), (-0.5, 1.5)]),
        ("threshold_saturation", ["threshold", "saturation"],
         [[0.05, 0.9], [0.1, 0.7], [0.2, 1.0], [0.0, 0.6]], [(0.0, 0.9), (0.1, 1.0)]),
    ]
    for shape, names, starts, bounds in trials:
        def cost(v, shape=shape, names=names):
            params = {"shape": shape, **dict(zip(names, (float(x) for x in v)))}
            try:
                m = net_static_map(_sim_h(params), sE_levels)
            except Exception:  # an invalid combination (e.g. threshold >= saturation)
                return 1e6
            return float(np.sum((m - target) ** 2))
        for s0 in starts:
            r = optimize.minimize(cost, s0, method="Nelder-Mead",
                                  options={"xatol": 1e-4, "fatol": 1e-10, "maxiter": 400})
            lo = np.array([bd[0] for bd in bounds])
            hi = np.array([bd[1] for bd in bounds])
            v = np.clip(r.x, lo, hi)
            c = cost(v)
            if c < best_cost:
                best_cost = c
                best = {"shape": shape, **dict(zip(names, (float(x) for x in v)))}
    return best


def effect_entries(params: dict, effects, sE_levels) -> list[dict]:
    """Twin-file ``effects`` entries for the fitted parameters (our names -> the
    simulator's)."""
    out = []
    for e in effects:
        if e is Effect.DEAD_TIME:
            out.append({"name": e.value, "params": {"L_s": params["L_s"]}})
        elif e is Effect.ACTIVATION_DYNAMICS:
            out.append({"name": e.value, "params": {"tau_s": params["tau_s"]}})
        elif e is Effect.FATIGUE:
            out.append({"name": e.value, "params": {
                "shape": "exponential",
                "gain_loss_pct": max(0.0, fatigue_loss_pct(params["rate_per_s"])),
                "reference_stim_s": REFERENCE_STIM_S}})
        elif e is Effect.RECRUITMENT_NONLINEARITY:
            out.append({"name": e.value, "params": project_recruitment(
                params["_curve"], sE_levels)})
        elif e is Effect.BASELINE_DRIFT:
            out.append({"name": e.value, "params": {
                "amplitude_N": params.get("amplitude_N", 0.0),
                "corner_Hz": params["corner_Hz"]}})
        elif e is Effect.FLEXOR_EXTENSOR_ASYMMETRY:
            out.append({"name": e.value, "params": {"wn_ratio": params["wn_ratio"],
                                                    "zeta_ratio": params["zeta_ratio"]}})
    order = ["recruitment_nonlinearity", "activation_dynamics", "flexor_extensor_asymmetry",
             "dead_time", "fatigue", "baseline_drift"]
    return sorted(out, key=lambda d: order.index(d["name"]))


def _curve(sE: np.ndarray, values: np.ndarray) -> dict:
    ok = np.isfinite(values)
    best = None
    for model in ("linear", "quadratic", "exponential"):
        try:
            f = fit_curve(model, sE[ok], values[ok])
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            continue
        if f.selectable and (best is None or f.aicc < best.aicc):
            best = f
    if best is None:
        return {"model": "constant", "coefficients": [float(np.nanmean(values))]}
    return {"model": best.model, "coefficients": [float(c) for c in best.coefficients]}


def twin_dict(*, participant: str, source: list[str], calibration, sE_levels, Kp, wn_rad_s,
              zeta, effects: list[dict]) -> dict:
    """A twin file's content (``docs/twin-file.md``)."""
    sE = np.asarray(sE_levels, float)
    cal = {k: float(getattr(calibration, k)) for k in
           ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N")}
    return {
        "format": "nmsid-twin", "format_version": 1, "participant": participant,
        "source": list(source), "calibration": cal,
        "sE_range": [float(sE.min()), float(sE.max())],
        "parameters": {"Kp": _curve(sE, np.asarray(Kp, float)),
                       "wn_rad_s": _curve(sE, np.asarray(wn_rad_s, float)),
                       "zeta": _curve(sE, np.asarray(zeta, float))},
        "offset_N": {"model": "constant", "coefficients": [0.0]},
        "effects": effects,
    }


def write_twin(path, twin: dict) -> None:
    """Write the twin file (UTF-8 JSON)."""
    Path(path).write_text(json.dumps(twin, indent=2) + "\n", encoding="utf-8")
