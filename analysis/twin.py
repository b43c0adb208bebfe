"""The digital twin: parameter curves of sE and the force they predict (``docs/twin-file.md``).

``F(t) = offset_N(sE) + y(t)`` with ``y'' + 2 zeta wn y' + wn^2 y = Kp wn^2 (rE(t) - 0.5)``
and Kp, wn, zeta evaluated at the current sE. :meth:`Twin.simulate` solves it exactly for
rE (and Kp) linear between samples: with a constant sE by ``lfilter`` on the triangle-hold
transfer function, with a time-varying sE by stepping the exact transition matrices of
each interval (parameters frozen at the interval's mid-point sE). The ``effects`` list is
kept as data; ``sim_backends`` applies it.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from nmsid.analysis.curves import evaluate_curve
from nmsid.analysis.discretize import foh_coefficients, foh_state_matrices
from nmsid.analysis.errors import IdentificationError, TwinFileError, TwinInputError
from nmsid.protocols.joints import QUANTITY_UNITS
from nmsid.protocols.reprs import html_repr, short_repr
from nmsid.sim_backends.twin_file import TwinReadError, read_twin_file, write_twin_file

FORMAT = "nmsid-twin"
FORMAT_VERSION = 1
_N_COEF = {"linear": 2, "quadratic": 3, "exponential": 2, "constant": 1}
_PARAMS = ("Kp", "wn_rad_s", "zeta")
_SHA256_HEX = frozenset("0123456789abcdef")


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes, as 64 lower-case hex digits."""
    digest = hashlib.sha256()
    block = bytearray(1 << 20)      # one buffer refilled: no fresh 1 MB object per block
    view = memoryview(block)
    with open(path, "rb", buffering=0) as fh:
        while n := fh.readinto(block):
            digest.update(view[:n])
    return digest.hexdigest()


def source_entry(source) -> dict | str:
    """How a twin names one source session: its file name and content hash.

    A twin is shared between people and machines, so it never records where a session
    lay on the machine that made it (a private path): only ``{"file": name, "sha256":
    hex}``, which identifies the recording wherever a copy of it lives.

    Parameters
    ----------
    source : str, os.PathLike or dict
        A session file's path, an entry already in this form (returned unchanged), or a
        label that is not a file (such as ``"sim_backends"``, returned as a string).

    Returns
    -------
    dict or str
    """
    if isinstance(source, dict):
        return dict(source)
    p = Path(source)
    if p.is_file():
        return {"file": p.name, "sha256": file_sha256(p)}
    return str(source)


def _source_from(obj, where: str, path) -> dict | str:
    """One ``source`` item of a twin file: a string (version-1 files written before the
    hash, or a label) or ``{"file": name, "sha256": 64 hex digits}``."""
    if isinstance(obj, str):
        return obj
    if (isinstance(obj, dict) and isinstance(obj.get("file"), str)
            and ("sha256" not in obj or (isinstance(obj["sha256"], str)
                                         and len(obj["sha256"]) == 64
                                         and set(obj["sha256"]) <= _SHA256_HEX))):
        return dict(obj)
    raise TwinFileError(path, f"{where} must be a file name or {{\"file\": name, "
                              f"\"sha256\": 64 lower-case hex digits}}, got {obj!r}")


@dataclass
class Curve:
    """A parameter as a function of sE."""

    model: str
    coefficients: list[float]

    def __call__(self, sE) -> np.ndarray:
        return evaluate_curve(self.model, self.coefficients, sE)

    def to_dict(self) -> dict:
        return {"model": self.model, "coefficients": [float(c) for c in self.coefficients]}


def _curve_from(obj, where: str, path) -> Curve:
    if not isinstance(obj, dict) or "model" not in obj or "coefficients" not in obj:
        raise TwinFileError(path, f"{where} must be an object with 'model' and "
                                  "'coefficients'")
    model = obj["model"]
    if model not in _N_COEF:
        raise TwinFileError(path, f"{where}.model is {model!r}; use one of {list(_N_COEF)}")
    coef = obj["coefficients"]
    if (not isinstance(coef, list) or len(coef) != _N_COEF[model]
            or not all(isinstance(c, (int, float)) and math.isfinite(c) for c in coef)):
        raise TwinFileError(path, f"{where}.coefficients must be {_N_COEF[model]} finite "
                                  f"number(s) for the {model} model, got {coef!r}")
    return Curve(model, [float(c) for c in coef])


@dataclass
class Twin:
    """A participant's (or a group's) identified model, as a function of sE."""

    participant: str
    parameters: dict[str, Curve]
    sE_range: tuple[float, float]
    offset_N: Curve = field(default_factory=lambda: Curve("constant", [0.0]))
    calibration: dict = field(default_factory=dict)
    source: list[dict | str] = field(default_factory=list)
    effects: list[dict] = field(default_factory=list)
    # -- muscle form (issue 20): optional physiological twin, analysis.muscle.twin_form --
    muscle_model: dict | None = None
    """The ``muscle_model`` item when the file has one; :meth:`simulate` then runs it."""
    joint: str = "elbow"
    """The joint it was identified on (``docs/joints.md``); the file's optional ``joint``."""
    measured_quantity: str = "force"
    """``force`` or ``torque``: what :meth:`simulate` returns (in :attr:`measured_unit`)."""
    measured_unit: str = "N"
    """``N`` or ``N m``: the unit of Kp (per unit rE), ``offset_N`` and the output."""

    def __repr__(self) -> str:
        curves = ", ".join(f"{name} {curve.model}" for name, curve in self.parameters.items())
        kinds = [str(e.get("name", "?")) for e in self.effects]
        return short_repr("Twin", self.participant or "no participant",
                          f"sE {self.sE_range[0]:g}-{self.sE_range[1]:g}", curves,
                          f"effects {', '.join(kinds)}" if kinds else "",
                          "muscle model" if self.muscle_model is not None else "")

    _repr_html_ = html_repr

    # -- parameters -----------------------------------------------------------------
    def parameters_at(self, sE, clip: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Kp, wn_rad_s, zeta) at sE (scalar or array).

        Parameters
        ----------
        sE : float or array-like
        clip : bool
            Clip sE to ``sE_range`` first (no extrapolation beyond the tested range).

        Raises
        ------
        ValueError
            If a parameter is not positive there (wn and zeta must be > 0).
        """
        x = np.asarray(sE, dtype=float)
        if clip:
            x = np.clip(x, *self.sE_range)
        kp = self.parameters["Kp"](x)
        wn = self.parameters["wn_rad_s"](x)
        zeta = self.parameters["zeta"](x)
        if np.any(~(wn > 0)) or np.any(~(zeta > 0)):
            bad = x[np.flatnonzero(~((wn > 0) & (zeta > 0)))[0]] if x.ndim else x
            raise TwinInputError(f"twin of {self.participant}: wn or zeta is not positive at "
                             f"sE = {float(bad):g} (wn={np.ravel(wn)[0]:.3g}, "
                             f"zeta={np.ravel(zeta)[0]:.3g}); clip sE to the tested range "
                             f"{self.sE_range[0]:g}-{self.sE_range[1]:g}")
        return kp, wn, zeta

    # -- simulation -----------------------------------------------------------------
    def simulate(self, rE, sE, fs_Hz: float, clip: bool = True) -> np.ndarray:
        """Force in N for an rE(t) and sE: the muscle form when the twin has one
        (:func:`nmsid.analysis.muscle.twin_form.simulate_muscle`), else the second-order form
        (:meth:`_simulate_second_order`, where the parameters are described)."""
        if self.muscle_model is not None:   # muscle form: its own dynamics (issue 20)
            from nmsid.analysis.muscle.twin_form import simulate_muscle  # lazy: muscle form only
            s = np.broadcast_to(np.asarray(sE, float), np.shape(rE))
            return simulate_muscle(self.muscle_model, rE, sE, fs_Hz) + \
                self.offset_N(np.clip(s, *self.sE_range) if clip else s)
        return self._simulate_second_order(rE, sE, fs_Hz, clip)

    def _simulate_second_order(self, rE, sE, fs_Hz: float, clip: bool = True) -> np.ndarray:
        """Force in N for an rE(t) and sE (constant or one value per sample).

        Parameters
        ----------
        rE : array-like
            EAA ratio per sample (the system starts at rest, i.e. as if rE had been 0.5).
        sE : float or array-like
            EAA sum, constant or per sample.
        fs_Hz : float
            Sampling rate.
        clip : bool
            Clip sE to ``sE_range`` (no extrapolation).

        Returns
        -------
        ndarray
            Force in N, one value per sample.

        Examples
        --------
        >>> import numpy as np
        >>> tw = Twin("P01", {"Kp": Curve("constant", [5.0]),
        ...                   "wn_rad_s": Curve("constant", [30.0]),
        ...                   "zeta": Curve("constant", [0.7])}, (0.3, 1.0))
        >>> f = tw.simulate(np.full(4000, 0.7), 0.5, 2000.0)   # a step of 0.2 in rE
        >>> round(float(f[-1]), 6)                               # settles at Kp * 0.2
        1.0
        """
        r = np.asarray(rE, dtype=float)
        if r.ndim != 1:
            raise ValueError(f"rE must be 1-D, got shape {r.shape}")
        if not fs_Hz > 0:
            raise ValueError(f"fs_Hz = {fs_Hz!r} must be > 0")
        s = np.asarray(sE, dtype=float)
        if s.ndim == 1 and len(s) != len(r):
            raise ValueError(f"sE has {len(s)} values but rE has {len(r)}; give one sE or "
                             "one per sample")
        if not np.all(np.isfinite(r)) or not np.all(np.isfinite(s)):
            raise TwinInputError("rE and sE must be finite numbers (a value in the input is "
                                 "NaN or infinite)")
        dt = 1.0 / fs_Hz
        n = len(r)
        if s.ndim == 0 or np.all(s == s.flat[0]):
            s0 = float(s.flat[0]) if s.size else 0.5
            kp0, wn0, zeta0 = (float(v) for v in self.parameters_at(s0, clip))
            num, den = foh_coefficients(wn0, zeta0, dt)
            # prepend the rest state (rE = 0.5 before the first sample)
            y = lfilter(num, den, np.concatenate([[0.0], kp0 * (r - 0.5)]))[1:]
            return y + float(self.offset_N(np.clip(s0, *self.sE_range) if clip else s0))
        kp, wn, zeta = self.parameters_at(s, clip)
        # as in the constant path, the record is preceded by one sample at rest
        # (rE = 0.5): n intervals, each with the parameters at its mid-point
        wn_e = np.concatenate([wn[:1], wn])
        zeta_e = np.concatenate([zeta[:1], zeta])
        phi, g0, g1 = foh_state_matrices(0.5 * (wn_e[1:] + wn_e[:-1]),
                                         0.5 * (zeta_e[1:] + zeta_e[:-1]), dt)
        w = [0.0] + (kp * (r - 0.5)).tolist()
        p = phi.reshape(n, 4).tolist()
        a0 = g0.tolist()
        a1 = g1.tolist()
        y = [0.0] * n
        x0 = x1 = 0.0
        for k in range(n):
            p00, p01, p10, p11 = p[k]
            wk, wk1 = w[k], w[k + 1]
            x0, x1 = (p00 * x0 + p01 * x1 + a0[k][0] * wk + a1[k][0] * wk1,
                      p10 * x0 + p11 * x1 + a0[k][1] * wk + a1[k][1] * wk1)
            y[k] = x0
        y_arr = np.asarray(y)
        offset = self.offset_N(np.clip(s, *self.sE_range) if clip else s)
        return y_arr + offset

    # -- file -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "format_version": FORMAT_VERSION,
            "participant": self.participant,
            "source": [dict(s) if isinstance(s, dict) else str(s) for s in self.source],
            "calibration": dict(self.calibration),
            "sE_range": [float(self.sE_range[0]), float(self.sE_range[1])],
            "parameters": {k: v.to_dict() for k, v in self.parameters.items()},
            "offset_N": self.offset_N.to_dict(),
            "effects": list(self.effects),
            **({"muscle_model": dict(self.muscle_model)} if self.muscle_model else {}),
            # optional (docs/joints.md): absent, the twin is an elbow's force twin
            **({"joint": self.joint, "measured_quantity": self.measured_quantity,
                "measured_unit": self.measured_unit}
               if (self.joint, self.measured_quantity) != ("elbow", "force") else {}),
        }

    def save(self, path: str | os.PathLike) -> None:
        """Write the twin as JSON (UTF-8). JSON has no NaN: a non-finite calibration value
        is written as ``null`` with a line in ``caveats``; a non-finite curve coefficient
        or sE range refuses the twin (:class:`TwinFileError`, nothing written)."""
        data = self.to_dict()
        for where, curve in [*(("parameters." + k, v) for k, v in data["parameters"].items()),
                             ("offset_N", data["offset_N"])]:
            if not all(math.isfinite(float(c)) for c in curve["coefficients"]):
                raise TwinFileError(path, f"{where} has a non-finite coefficient "
                                          f"{curve['coefficients']}; twin not written")
        if not all(math.isfinite(v) for v in data["sE_range"]):
            raise TwinFileError(path, f"sE_range {data['sE_range']} is not finite; twin not "
                                      "written")
        caveats = []
        for key, value in list(data["calibration"].items()):
            if isinstance(value, float) and not math.isfinite(value):
                data["calibration"][key] = None
                caveats.append(f"calibration.{key} was {value!r} (not a number JSON can "
                               "hold): written as null")
        if caveats:
            data["caveats"] = caveats
        write_twin_file(path, data)      # the one writer of twin files

    @classmethod
    def from_dict(cls, data: dict, path: str | os.PathLike = "<twin>") -> Twin:
        """Build and check a twin from its JSON object (errors name the item)."""
        if not isinstance(data, dict):
            raise TwinFileError(path, "is not a JSON object")
        if data.get("format") != FORMAT:
            raise TwinFileError(path, f"format is {data.get('format')!r}, expected {FORMAT!r}")
        if data.get("format_version") != FORMAT_VERSION:
            raise TwinFileError(path, f"format_version is {data.get('format_version')!r}; "
                                      f"this reader knows {FORMAT_VERSION}")
        params = data.get("parameters")
        if not isinstance(params, dict):
            raise TwinFileError(path, "missing 'parameters' object")
        curves = {}
        for name in _PARAMS:
            if name not in params:
                raise TwinFileError(path, f"parameters.{name} is missing")
            curves[name] = _curve_from(params[name], f"parameters.{name}", path)
        rng = data.get("sE_range")
        if (not isinstance(rng, list) or len(rng) != 2
                or not all(isinstance(v, (int, float)) for v in rng) or not rng[0] <= rng[1]):
            raise TwinFileError(path, f"sE_range must be [low, high] with low <= high, got {rng!r}")
        offset = _curve_from(data.get("offset_N", {"model": "constant", "coefficients": [0.0]}),
                             "offset_N", path)
        effects = data.get("effects", [])
        if not isinstance(effects, list) or not all(
                isinstance(e, dict) and isinstance(e.get("name"), str) for e in effects):
            raise TwinFileError(path, "effects must be a list of {\"name\": ..., \"params\": "
                                      "{...}} objects")
        source = data.get("source", [])
        source = [_source_from(item, f"source[{i}]", path) for i, item in
                  enumerate(source if isinstance(source, list) else [source])]
        muscle = None
        if data.get("muscle_model") is not None:     # muscle form (issue 20), optional
            from nmsid.analysis.muscle.twin_form import parse_muscle_model  # lazy: muscle form only
            muscle = parse_muscle_model(data["muscle_model"], path)
        joint = data.get("joint", "elbow")
        quantity = data.get("measured_quantity", "force")
        if not isinstance(joint, str) or not joint or quantity not in QUANTITY_UNITS:
            raise TwinFileError(path, f"joint {joint!r} / measured_quantity {quantity!r}: "
                                      "expected a joint name and one of "
                                      + ", ".join(QUANTITY_UNITS))
        return cls(participant=str(data.get("participant", "")), parameters=curves,
                   muscle_model=muscle, joint=joint, measured_quantity=quantity,
                   measured_unit=QUANTITY_UNITS[quantity],
                   sE_range=(float(rng[0]), float(rng[1])), offset_N=offset,
                   calibration=dict(data.get("calibration") or {}),
                   source=source,
                   effects=effects)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Twin:
        """Read a twin file; errors name the file and the item."""
        p = Path(path)
        try:
            data = read_twin_file(p)      # the one reader of twin files
        except TwinReadError as exc:
            raise TwinFileError(p, exc.problem) from None
        return cls.from_dict(data, p)


def twin_from_selection(selection, label: str, *, baseline_N: float = 0.0,
                        calibration: dict | None = None, source=(),
                        measured: tuple[str, str, str] = ("elbow", "force", "N")) -> Twin:
    """A twin from the selected curves of one participant (or ``average``).

    ``source`` lists the session files (paths) the twin comes from; the twin keeps each
    one's file name and content hash (:func:`source_entry`), never its path.
    ``measured``: the sessions' ``(joint, quantity, unit)``
    (:func:`nmsid.protocols.joints.recorded_quantity`).

    Raises
    ------
    ValueError
        If a parameter has no selected model (the message says which and why).
    """
    curves = {}
    lo, hi = math.inf, -math.inf
    for name in _PARAMS:
        comp = selection.comparison(name, label)
        if comp is None or comp.selected is None:
            why = "; ".join(comp.problems) if comp else "no comparison"
            raise IdentificationError(f"no twin for {label}: {name} has no selected model ({why})")
        curves[name] = Curve(comp.selected, list(comp.selected_fit.coefficients))
        x, _ = comp.used_points()
        lo, hi = min(lo, float(x.min())), max(hi, float(x.max()))
    offset = Curve("constant", [float(baseline_N) if math.isfinite(baseline_N) else 0.0])
    return Twin(participant=label, parameters=curves, sE_range=(lo, hi), offset_N=offset,
                calibration=dict(calibration or {}),
                source=[source_entry(s) for s in source], joint=measured[0],
                measured_quantity=measured[1], measured_unit=measured[2])
