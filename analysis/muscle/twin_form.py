"""The muscle form of ``twin.json`` (an optional item, ``docs/twin-file.md``).

``"muscle_model": {"form": "hill2-isometric", "form_version": 1, "params": {...},
"fit_fs_Hz": 100}``: the physiological twin's parameters (:data:`PARAM_NAMES`, physical
units), the rate it was fitted at, and optionally ``"uncertainty"`` and
``"not_determined"`` (information only). A twin file with it still holds the second-order
form (parameters per sE), which every other reader keeps using.
"""

from __future__ import annotations

import math

import numpy as np

from nmsid.analysis.errors import TwinFileError
from nmsid.analysis.muscle.dynamics import PARAM_NAMES, simulate_batch

FORM = "hill2-isometric"
FORM_VERSION = 1


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
    if obj.get("form") != FORM or obj.get("form_version") != FORM_VERSION:
        raise TwinFileError(path, f"muscle_model form {obj.get('form')!r} version "
                                  f"{obj.get('form_version')!r}: this reader knows "
                                  f"{FORM!r} version {FORM_VERSION}")
    params = obj.get("params")
    if not isinstance(params, dict):
        raise TwinFileError(path, "muscle_model.params is missing")
    for name in PARAM_NAMES:
        v = params.get(name)
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            raise TwinFileError(path, f"muscle_model.params.{name} must be a finite number, "
                                      f"got {v!r}")
        if name not in ("c_e", "c_f") and v <= 0:
            raise TwinFileError(path, f"muscle_model.params.{name} must be > 0, got {v!r}")
    return dict(obj)


def simulate_muscle(entry: dict, rE, sE, fs_Hz: float) -> np.ndarray:
    """Force (offset-free, N) of the muscle form for rE(t) and sE (constant or per sample),
    from the lead-in's steady state; the input of each step is its mid-step value."""
    rE = np.asarray(rE, float)
    s = np.broadcast_to(np.asarray(sE, float), rE.shape)
    theta = np.array([entry["params"][n] for n in PARAM_NAMES], float)
    r_mid = np.concatenate([[rE[0]], 0.5 * (rE[1:] + rE[:-1])])
    s_mid = np.concatenate([[s[0]], 0.5 * (s[1:] + s[:-1])])
    return simulate_batch(theta[None], r_mid[None], s_mid[None], 1.0 / fs_Hz)[0, 0]
