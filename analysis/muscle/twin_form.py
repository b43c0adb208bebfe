"""The muscle form of ``twin.json`` (an optional item, ``docs/twin-file.md``).

``"muscle_model": {"form": "hill2-isometric", "form_version": 2, "params": {...},
"fit_fs_Hz": 100}``: the physiological twin's parameters (:data:`PARAM_NAMES`, physical
units), the rate it was fitted at, and optionally ``"uncertainty"`` and
``"not_determined"`` (information only). A twin file with it still holds the second-order
form (parameters per sE), which every other reader keeps using.

Version 1 (14 parameters: one active stiffness ``k_s`` for both muscles, no recruitment
threshold, no delay) is still read: it is version 2 with ``k_e = k_f = k_s``,
``th_e = th_f = 0`` and ``delay_s = 0``, which simulates exactly as version 1 did.
"""

from __future__ import annotations

import math

import numpy as np

from nmsid.analysis.errors import TwinFileError
from nmsid.analysis.muscle.dynamics import PARAM_NAMES, simulate_batch

FORM = "hill2-isometric"
FORM_VERSION = 2

#: Version 1's parameters.
V1_NAMES = ("F_e_N", "F_f_N", "c_e", "c_f", "w_e", "w_f", "tau_act_s", "tau_deact_s",
            "wn0_rad_s", "zeta0", "k_s", "c_s_per_s", "sensor_zero_s", "a_max")

#: Parameters that may be zero or negative (the others must be > 0).
SIGNED = ("c_e", "c_f", "k_e", "k_f", "delay_s", "th_e", "th_f")


def muscle_entry(fit, fs_fit_Hz: float) -> dict:
    """The ``muscle_model`` item for a :class:`nmsid.analysis.muscle.fit.MuscleFit`."""
    return {"form": FORM, "form_version": FORM_VERSION,
            "params": {k: float(v) for k, v in fit.params.items()},
            "fit_fs_Hz": float(fs_fit_Hz),
            "uncertainty": {r["name"]: {k: v for k, v in r.items() if k.startswith("sd")}
                            for r in fit.table()},
            "not_determined": [r["name"] for r in fit.table() if not r["determined"]]}


def parse_muscle_model(obj, path) -> dict:
    """Check a ``muscle_model`` item; errors name the file and the item.

    Raises
    ------
    TwinFileError
    """
    if not isinstance(obj, dict):
        raise TwinFileError(path, "muscle_model must be an object {\"form\": "
                                  f"\"{FORM}\", \"form_version\": 1, \"params\": {{...}}}}")
    version = obj.get("form_version")
    if obj.get("form") != FORM or version not in (1, FORM_VERSION):
        raise TwinFileError(path, f"muscle_model form {obj.get('form')!r} version "
                                  f"{version!r}: this reader knows {FORM!r} versions 1 "
                                  f"and {FORM_VERSION}")
    params = obj.get("params")
    if not isinstance(params, dict):
        raise TwinFileError(path, "muscle_model.params is missing")
    for name in (V1_NAMES if version == 1 else PARAM_NAMES):
        v = params.get(name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise TwinFileError(path, f"muscle_model.params.{name} must be a finite number, "
                                      f"got {v!r}")
        if name not in SIGNED and v <= 0:
            raise TwinFileError(path, f"muscle_model.params.{name} must be > 0, got {v!r}")
    for name in ("th_e", "th_f"):
        v = params.get(name, 0.0)
        if not -1.0 < v < 1.0:
            raise TwinFileError(path, f"muscle_model.params.{name} = {v!r}: a recruitment "
                                      "threshold must lie in (-1, 1) of the calibrated range")
    return dict(obj)


def theta_of(entry: dict) -> np.ndarray:
    """The physical parameter vector (:data:`PARAM_NAMES` order) of a checked entry, a
    version-1 entry completed as the module says."""
    p = dict(entry["params"])
    if entry.get("form_version") == 1:
        p.setdefault("k_e", p["k_s"])
        p.setdefault("k_f", p["k_s"])
        for name in ("delay_s", "th_e", "th_f"):
            p.setdefault(name, 0.0)
    return np.array([p[n] for n in PARAM_NAMES], float)


def simulate_muscle(entry: dict, rE, sE, fs_Hz: float) -> np.ndarray:
    """Force (offset-free, N) of the muscle form for rE(t) and sE (constant or per sample),
    from the lead-in's steady state; the input of each step is its mid-step value, and the
    output is shifted by ``delay_s`` (linear interpolation, held at the ends)."""
    rE = np.asarray(rE, float)
    s = np.broadcast_to(np.asarray(sE, float), rE.shape)
    theta = theta_of(entry)
    r_mid = np.concatenate([[rE[0]], 0.5 * (rE[1:] + rE[:-1])])
    s_mid = np.concatenate([[s[0]], 0.5 * (s[1:] + s[:-1])])
    y = simulate_batch(theta[None], r_mid[None], s_mid[None], 1.0 / fs_Hz)[0, 0]
    delay = float(theta[PARAM_NAMES.index("delay_s")])
    if delay != 0.0:
        t = np.arange(len(y)) / fs_Hz
        y = np.interp(t - delay, t, y)
    return y
