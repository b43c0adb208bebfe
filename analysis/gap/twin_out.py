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

from collections.abc import Mapping

import numpy as np

from nmsid.analysis.curves import fit_curve

# re-exported: the translations live with each effect's form (analysis.gap.models)
from nmsid.analysis.gap.models import (  # noqa: F401
    FORMS,
    fatigue_loss_pct,
    net_static_map,
    nonlinearity_index_pct,
    project_recruitment,
)
from nmsid.analysis.twin import Twin
from nmsid.protocols.effects import EFFECT_NAMES


def effect_entries(params: Mapping[str, float], effects, sE_levels) -> list[dict]:
    """Twin-file ``effects`` entries for the fitted parameters (our names -> the
    simulator's), in the registry's order of physics."""
    out = [{"name": e.value, "params": FORMS[e].twin_params(params, sE_levels)}
           for e in effects]
    return sorted(out, key=lambda d: EFFECT_NAMES.index(d["name"]))


def _curve(sE: np.ndarray, values: np.ndarray) -> dict:
    ok = np.isfinite(values)
    best = None
    for model in ("linear", "quadratic", "exponential"):
        try:
            f = fit_curve(model, sE[ok], values[ok])
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            continue
        if f.selectable and f.aicc is not None and (best is None or best.aicc is None
                                                    or f.aicc < best.aicc):
            best = f
    if best is None:
        return {"model": "constant", "coefficients": [float(np.nanmean(values))]}
    return {"model": best.model, "coefficients": [float(c) for c in best.coefficients]}


def twin_dict(*, participant: str, source: list[dict | str], calibration, sE_levels, Kp, wn_rad_s,
              zeta, effects: list[dict],
              measured: tuple[str, str, str] = ("elbow", "force", "N")) -> dict:
    """A twin file's content (``docs/twin-file.md``); ``measured`` the session's
    ``(joint, quantity, unit)``: recorded for any joint but the elbow's force (optional
    items, as :meth:`nmsid.analysis.twin.Twin.to_dict` writes them)."""
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
        **({"joint": measured[0], "measured_quantity": measured[1],
            "measured_unit": measured[2]} if tuple(measured[:2]) != ("elbow", "force")
           else {}),
    }


def write_twin(path, twin: dict) -> None:
    """Write the twin file through the one twin writer (:meth:`nmsid.analysis.twin.Twin.save`,
    which checks it as every reader will)."""
    Twin.from_dict(twin, path).save(path)
