"""Build a virtual participant from a twin file (``docs/twin-file.md``).

Examples
--------
>>> twin = {"format": "nmsid-twin", "format_version": 1, "participant": "P01",
...         "calibration": {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5,
...                         "Ifmax_mA": 8.0, "Fmin_N": 0.5, "Fmax_N": 5.0},
...         "sE_range": [0.3, 1.0],
...         "parameters": {"Kp": {"model": "exponential", "coefficients": [0.9, 1.6]},
...                        "wn_rad_s": {"model": "quadratic", "coefficients": [10, 40, -25]},
...                        "zeta": {"model": "linear", "coefficients": [0.4, 0.3]}},
...         "offset_N": {"model": "constant", "coefficients": [0.0]},
...         "effects": [{"name": "dead_time", "params": {"L_s": 0.02}}]}
>>> p = participant_from_twin(twin)
>>> round(p.true_parameters(0.5).wn_rad_s, 6), p.effect_truth()[0]["name"]
(23.75, 'dead_time')
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

from nmsid.errors import OutputExistsError
from nmsid.sim_backends.curves import ParameterCurve
from nmsid.sim_backends.effects import effects_from_list
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.participant import ReferenceCalibration, VirtualParticipant
from nmsid.sim_backends.sensor import SensorModel
from nmsid.sim_backends.twin_file import read_twin_file, write_twin_file

log = logging.getLogger(__name__)


def load_twin(path_or_dict) -> dict:
    """The twin as a dict (from a path or a dict), with its format checked."""
    if isinstance(path_or_dict, dict):
        twin, where = path_or_dict, "twin"
    else:
        where = os.fspath(path_or_dict)
        twin = read_twin_file(where)
    if not isinstance(twin, dict):
        raise SimConfigError(f"{where}: a twin file holds a JSON object")
    if twin.get("format") != "nmsid-twin":
        raise SimConfigError(f"{where}: 'format' must be 'nmsid-twin', got "
                             f"{twin.get('format')!r}")
    if twin.get("format_version") != 1:
        raise SimConfigError(f"{where}: format_version {twin.get('format_version')!r} is "
                             "not supported (valid: 1)")
    for key in ("calibration", "parameters"):
        if key not in twin:
            raise SimConfigError(f"{where}: missing '{key}'")
    return twin


def _snap_up(current_mA: float, step_mA: float) -> float:
    return round(math.ceil(current_mA / step_mA - 1e-9) * step_mA, 9)


def participant_from_twin(path_or_dict, *, sensor: SensorModel | None = None, seed: int = 0,
                          code: str | None = None, step_mA: float = 0.5,
                          snap_calibration: bool = True, effects=None
                          ) -> VirtualParticipant:
    """A virtual participant that runs the twin: its curves, calibration and effects.

    Parameters
    ----------
    path_or_dict : path or dict
        The twin file (or its parsed content).
    sensor : SensorModel, optional
        Force chain; default :class:`SensorModel` with its offset and drift at zero (the
        twin's ``offset_N`` already holds the offset measured in the session it came
        from), noise and mains pick-up as usual.
    seed : int
        Seeds the sensor noise and the baseline wander.
    code : str, optional
        Participant code; default the twin's ``participant``.
    step_mA : float
        Step of the calibration ramp the participant will meet.
    snap_calibration : bool
        Round the twin's currents up onto the ramp grid (``step, 2 step, ...``), so that a
        ramp on the simulated participant finds them again (twins written from ramp
        sessions are already on the grid; a hand-entered calibration may not be).
    effects : list, optional
        Replace the twin's effect list.

    Returns
    -------
    VirtualParticipant
        With linear recruitment and symmetric dynamics, its trials at constant sE are the
        twin's model exactly, in the coordinates of the twin's calibration.
    """
    twin = load_twin(path_or_dict)
    where = "twin" if isinstance(path_or_dict, dict) else os.fspath(path_or_dict)
    cal = twin["calibration"]
    names = ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA")
    if isinstance(cal, dict) and not any(k in cal for k in names):
        raise SimConfigError(f"{where}: the twin has no calibration (a group average of nmsid "
                             f"identify has none: its participants' currents differ); give "
                             f"one participant's twin (twin_<participant>.json beside it)")
    try:
        currents = {k: float(cal[k]) for k in names}
    except (KeyError, TypeError, ValueError):
        bad = next((k for k in names if not isinstance(cal, dict) or not isinstance(
            cal.get(k), (int, float)) or isinstance(cal.get(k), bool)), names[0])
        got = cal.get(bad) if isinstance(cal, dict) else cal
        raise SimConfigError(f"{where}: calibration.{bad} is {got!r}; the twin's calibration "
                             f"needs a number (mA) for each of {', '.join(names)}") from None
    if snap_calibration:
        snapped = {k: _snap_up(v, step_mA) for k, v in currents.items()}
        if snapped != currents:
            log.info("%s: calibration snapped onto the %g mA ramp grid: %s -> %s", where,
                     step_mA, currents, snapped)
        currents = snapped
    reference = ReferenceCalibration(**currents, Fmin_N=float(cal.get("Fmin_N", 0.5)),
                                     Fmax_N=float(cal.get("Fmax_N", 5.0)), step_mA=step_mA)
    params = twin["parameters"]
    curves = {}
    for name in ("Kp", "wn_rad_s", "zeta"):
        if name not in params:
            raise SimConfigError(f"{where}: parameters.{name} is missing")
        curves[name] = ParameterCurve.from_dict(params[name], f"{where}: parameters.{name}")
    offset = ParameterCurve.from_dict(twin.get("offset_N", {"model": "constant",
                                                            "coefficients": [0.0]}),
                                      f"{where}: offset_N")
    sE_range = tuple(twin.get("sE_range", (0.30, 1.00)))
    if len(sE_range) != 2:
        raise SimConfigError(f"{where}: sE_range must be [lo, hi], got {sE_range!r}")
    eff = effects_from_list(twin.get("effects", []) if effects is None else effects)
    return VirtualParticipant(
        code=code or str(twin.get("participant", "TWIN")), Kp=curves["Kp"],
        wn_rad_s=curves["wn_rad_s"], zeta=curves["zeta"], calibration=reference,
        offset_N=offset, sE_range=sE_range, effects=tuple(eff),
        sensor=sensor if sensor is not None else SensorModel(offset_N=0.0,
                                                             drift_N_per_s=0.0),
        seed=seed)


def write_twin(participant: VirtualParticipant, path) -> None:
    """Write a participant as a twin file (never overwrites)."""
    path = Path(path)
    if path.exists():
        raise OutputExistsError(f"{path}: already exists; choose another path")
    write_twin_file(path, participant.to_twin())
