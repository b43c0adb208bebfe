"""One validated configuration for a session: defaults built in, overridable by a TOML file.

Layout of the TOML file (every key optional; unknown keys are refused)::

    participant = "P01"
    seed = 1234                    # schedule randomisation seed (omitted: drawn and recorded)

    # or, to choose the simulated participant as well (instead of participant = "P01"):
    [participant]
    code = "P01"
    model = "template"             # --backend sim: "template" (the paper's model) |
                                   # "musculoskeletal" (MuJoCo elbow; the 'mujoco' extra)

    [protocol]
    sE_levels = [0.30, 0.35, ...]  # or sE_min / sE_max / sE_step
    repeats = 3
    randomisation = "blocks"       # "blocks" | "full"
    steady_s = 5.0
    chirp_s = 10.0
    chirp_f0_Hz = 1.0
    chirp_f1_Hz = 10.0
    rE_centre = 0.5
    rE_amplitude = 0.5
    fs_Hz = 2000.0
    carrier_Hz = 1000.0
    rest_s = 60.0
    pause_policy = "finish"        # "finish" | "abort" the trial in progress
    input_kind = "chirp"           # "chirp" (the paper's) | "multisine" (low-crest phases)
    multisine_tones = 24           # multisine only: tones in [chirp_f0_Hz, chirp_f1_Hz]

    [calibration]
    step_mA = 0.5
    hold_s = 1.0                   # stimulation time per ramp step
    settle_fraction = 0.5          # first part of each hold ignored before averaging force
    baseline_s = 1.0               # zero-current recording that tares the force (settled part)
    rest_s = 2.0                   # output off before each ramp's baseline (force settles)
    Fmin_N = 0.5
    Fmax_N = 5.0
    ceiling_ext_mA = 16.0              # the STG4002's full range; lower it per participant
    ceiling_flex_mA = 16.0
    force_ceiling_N = 10.0         # a ramp step above this ends the ramp
    confirm = false                # wait for the operator to confirm / edit the result

    [calibration.manual]           # all four, or none: skip the ramps
    Iemin_mA = 2.0
    Iemax_mA = 9.5
    Ifmin_mA = 1.5
    Ifmax_mA = 8.0

    [interlock]
    force_limit_N = 25.0
    stall_timeout_s = 0.1
    trip_on_overrun = true
    trip_on_over_range = true
    trip_on_sensor_fault = true
    estop_poll_Hz = 1000.0
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from typing import Any

from nmsid.protocols.errors import ConfigError

PARTICIPANT_PATTERN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
PARTICIPANT_MODELS = ("template", "musculoskeletal")
"""Simulated participants ``[participant] model`` can name: the paper's second-order model
with add-on effects (``sim_backends.participant``), or MyoSuite's MuJoCo elbow under FES
(``sim_backends.msk_participant``). Hardware sessions ignore it."""
DEFAULT_SOURCE = "built-in defaults"


class Randomisation(enum.Enum):
    """How the 45 trials are ordered."""

    BLOCKS = "blocks"
    """The order of sE blocks is random; the repeats of one sE run one after another."""
    FULL = "full"
    """All trials are shuffled."""


class InputKind(enum.Enum):
    """The excitation after the steady lead-in (``protocols.waveforms``)."""

    CHIRP = "chirp"
    """The paper's exponential chirp from chirp_f0_Hz to chirp_f1_Hz over chirp_s."""
    MULTISINE = "multisine"
    """A periodic sum of ``multisine_tones`` sines (period chirp_s) spread log-evenly over
    [chirp_f0_Hz, chirp_f1_Hz], low-crest phases, peak rE_amplitude. The chirp_*
    settings then mean the band and the excitation's length."""


class PausePolicy(enum.Enum):
    """What a pause does with the trial in progress."""

    FINISH = "finish"
    """Let the trial finish (its data are kept complete), then pause."""
    ABORT = "abort"
    """Stop output now; the trial is recorded as aborted and can be re-run."""


def _default_levels() -> tuple[float, ...]:
    return tuple(round(0.30 + 0.05 * k, 2) for k in range(15))


@dataclass(frozen=True)
class ManualCurrents:
    """Calibration currents entered by hand (skips the ramps)."""

    Iemin_mA: float
    Iemax_mA: float
    Ifmin_mA: float
    Ifmax_mA: float


@dataclass(frozen=True)
class CalibrationConfig:
    """Settings of the calibration ramps (paper: 0.5 mA steps, Fmin 0.5 N, Fmax 5 N)."""

    step_mA: float = 0.5
    hold_s: float = 1.0
    settle_fraction: float = 0.5
    baseline_s: float = 1.0
    rest_s: float = 2.0
    Fmin_N: float = 0.5
    Fmax_N: float = 5.0
    ceiling_ext_mA: float = 16.0
    ceiling_flex_mA: float = 16.0
    force_ceiling_N: float = 10.0
    confirm: bool = False
    manual: ManualCurrents | None = None


@dataclass(frozen=True)
class InterlockConfig:
    """Thresholds of the safety interlock (see ``docs/rig.md``)."""

    force_limit_N: float = 25.0
    stall_timeout_s: float = 0.1
    trip_on_overrun: bool = True
    trip_on_over_range: bool = True
    trip_on_sensor_fault: bool = True
    estop_poll_Hz: float = 1000.0


@dataclass(frozen=True)
class ProtocolConfig:
    """The identification protocol (paper: 15 sE x 3 repeats, 5 s steady + 10 s chirp)."""

    sE_levels: tuple[float, ...] = field(default_factory=_default_levels)
    repeats: int = 3
    randomisation: Randomisation = Randomisation.BLOCKS
    steady_s: float = 5.0
    chirp_s: float = 10.0
    chirp_f0_Hz: float = 1.0
    chirp_f1_Hz: float = 10.0
    rE_centre: float = 0.5
    rE_amplitude: float = 0.5
    fs_Hz: float = 2000.0
    carrier_Hz: float = 1000.0
    rest_s: float = 60.0
    pause_policy: PausePolicy = PausePolicy.FINISH
    input_kind: InputKind = InputKind.CHIRP
    multisine_tones: int = 24

    @property
    def trial_s(self) -> float:
        return self.steady_s + self.chirp_s

    @property
    def n_samples(self) -> int:
        """Samples per trial."""
        return int(round(self.trial_s * self.fs_Hz))


@dataclass(frozen=True)
class Config:
    """Everything a session needs, validated on construction through :func:`load_config`."""

    participant: str = "P01"
    seed: int | None = None
    participant_model: str = "template"
    """Which simulated participant ``--backend sim`` puts on the rig
    (:data:`PARTICIPANT_MODELS`); TOML ``[participant] model``."""
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    interlock: InterlockConfig = field(default_factory=InterlockConfig)
    source: str = DEFAULT_SOURCE
    """Where the values came from (for messages); not stored."""

    # -- conversion ---------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict with the TOML layout (``source`` left out)."""
        def conv(obj):
            if dataclasses.is_dataclass(obj):
                return {f.name: conv(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                        if f.name != "source"}
            if isinstance(obj, enum.Enum):
                return obj.value
            if isinstance(obj, tuple):
                return [conv(v) for v in obj]
            return obj
        d = conv(self)
        if d["calibration"]["manual"] is None:
            del d["calibration"]["manual"]
        if d["seed"] is None:
            del d["seed"]
        model = d.pop("participant_model")
        if model != "template":     # the plain string form otherwise (older readers)
            d["participant"] = {"code": d["participant"], "model": model}
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def replace(self, **changes) -> Config:
        """A copy with top-level fields changed, validated again."""
        new = dataclasses.replace(self, **changes)
        validate(new)
        return new

    def with_protocol(self, **changes) -> Config:
        """A copy with protocol fields changed, validated again."""
        return self.replace(protocol=dataclasses.replace(self.protocol, **changes))

    def check_device(self, max_current_mA: float, device_name: str = "stimulator") -> None:
        """Refuse current ceilings above what the device can deliver.

        Raises
        ------
        ConfigError
            If a ceiling (or a manual current) is above ``max_current_mA``.
        """
        for name in ("ceiling_ext_mA", "ceiling_flex_mA"):
            value = getattr(self.calibration, name)
            if value > max_current_mA:
                raise ConfigError(self.source, f"calibration.{name}", value,
                                  f"the {device_name} delivers at most {max_current_mA:g} mA; "
                                  f"use a ceiling <= {max_current_mA:g}")


# -- loading --------------------------------------------------------------------------
_SECTIONS = {"protocol": ProtocolConfig, "calibration": CalibrationConfig,
             "interlock": InterlockConfig}
_TOP_KEYS = ("participant", "seed", *_SECTIONS)
_LEVEL_RANGE_KEYS = ("sE_min", "sE_max", "sE_step")


def load_config(path: str | os.PathLike | None = None, *, overrides: dict | None = None
                ) -> Config:
    """Load and validate a configuration.

    Parameters
    ----------
    path : path-like, optional
        A TOML file; None uses the built-in defaults.
    overrides : dict, optional
        Top-level values that win over the file (``{"participant": "P07", "seed": 3}``),
        as given on the command line.

    Returns
    -------
    Config

    Raises
    ------
    ConfigError
        Naming the file, the setting, the value and what is valid.
    OSError
        If the file cannot be read.
    """
    source = DEFAULT_SOURCE
    data: dict[str, Any] = {}
    if path is not None:
        source = str(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(
                f"{source}: no such configuration file (give a TOML file with --config, "
                "or leave --config out for the built-in paper protocol)")
        with open(path, "rb") as fh:
            try:
                data = tomllib.load(fh)
            except tomllib.TOMLDecodeError as exc:
                raise ConfigError(source, "(file)", "TOML", f"not valid TOML: {exc}") from None
    for key, value in (overrides or {}).items():
        if value is not None:
            if key == "participant" and isinstance(data.get("participant"), dict):
                data["participant"] = {**data["participant"], "code": value}
            else:
                data[key] = value
    return config_from_dict(data, source=source)


def config_from_json(text: str, source: str = "session file config_json") -> Config:
    """Rebuild a configuration stored with a session (``Config.to_json``)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(source, "config_json", text[:40], f"not valid JSON: {exc}") from None
    return config_from_dict(data, source=source)


def config_from_dict(data: dict[str, Any], *, source: str = DEFAULT_SOURCE) -> Config:
    """Build and validate a :class:`Config` from a dict with the TOML layout."""
    if not isinstance(data, dict):
        raise ConfigError(source, "(top level)", data, "a table of settings")
    _refuse_unknown(data, _TOP_KEYS, "", source)
    kwargs: dict[str, Any] = {"source": source}
    if "participant" in data:
        raw = data["participant"]
        if isinstance(raw, dict):       # the [participant] table: code and model
            _refuse_unknown(raw, ("code", "model"), "participant.", source)
            if "code" in raw:
                kwargs["participant"] = raw["code"]
            if "model" in raw:
                kwargs["participant_model"] = raw["model"]
        else:
            kwargs["participant"] = raw
    if "seed" in data:
        kwargs["seed"] = data["seed"]
    for section, cls in _SECTIONS.items():
        raw = data.get(section, {})
        if not isinstance(raw, dict):
            raise ConfigError(source, section, raw, "a table ([%s])" % section)
        kwargs[section] = _build_section(cls, section, dict(raw), source)
    cfg = Config(**kwargs)
    validate(cfg)
    return cfg


def _refuse_unknown(raw: dict, known, prefix: str, source: str) -> None:
    for key in raw:
        if key not in known:
            raise ConfigError(source, prefix + key, raw[key],
                              "unknown setting; known settings here are: "
                              + ", ".join(sorted(known)))


def _build_section(cls, section: str, raw: dict, source: str):
    names = [f.name for f in dataclasses.fields(cls)]
    known = list(names)
    if cls is ProtocolConfig:
        known += list(_LEVEL_RANGE_KEYS)
    _refuse_unknown(raw, known, section + ".", source)
    kw: dict[str, Any] = {}
    if cls is ProtocolConfig:
        if any(k in raw for k in _LEVEL_RANGE_KEYS):
            if "sE_levels" in raw:
                raise ConfigError(source, "protocol.sE_levels", raw["sE_levels"],
                                  "give either sE_levels or sE_min/sE_max/sE_step, not both")
            kw["sE_levels"] = _levels_from_range(raw, source)
            for k in _LEVEL_RANGE_KEYS:
                raw.pop(k, None)
        if "sE_levels" in raw:
            levels = raw.pop("sE_levels")
            if not isinstance(levels, (list, tuple)) or not levels:
                raise ConfigError(source, "protocol.sE_levels", levels,
                                  "a non-empty list of numbers in (0, 1]")
            kw["sE_levels"] = tuple(_number(source, "protocol.sE_levels", v) for v in levels)
        for key, enum_cls in (("randomisation", Randomisation), ("pause_policy", PausePolicy),
                              ("input_kind", InputKind)):
            if key in raw:
                value = raw.pop(key)
                try:
                    kw[key] = enum_cls(value)
                except ValueError:
                    raise ConfigError(source, f"protocol.{key}", value, "one of " + ", ".join(
                        repr(m.value) for m in enum_cls)) from None
    if cls is CalibrationConfig and "manual" in raw:
        manual = raw.pop("manual")
        mnames = [f.name for f in dataclasses.fields(ManualCurrents)]
        if not isinstance(manual, dict):
            raise ConfigError(source, "calibration.manual", manual, "a table with " +
                              ", ".join(mnames))
        _refuse_unknown(manual, mnames, "calibration.manual.", source)
        missing = [n for n in mnames if n not in manual]
        if missing:
            raise ConfigError(source, "calibration.manual", manual,
                              "give all four currents (missing: " + ", ".join(missing) + ")")
        kw["manual"] = ManualCurrents(**{n: _number(source, f"calibration.manual.{n}",
                                                    manual[n]) for n in mnames})
    types = {f.name: f.type for f in dataclasses.fields(cls)}
    for key, value in raw.items():
        setting = f"{section}.{key}"
        t = str(types[key])
        if t == "bool":
            if not isinstance(value, bool):
                raise ConfigError(source, setting, value, "true or false")
            kw[key] = value
        elif t == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(source, setting, value, "a whole number")
            kw[key] = value
        else:
            kw[key] = _number(source, setting, value)
    return cls(**kw)


def _number(source: str, setting: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(source, setting, value, "a number")
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(source, setting, value, "a finite number")
    return value


def _levels_from_range(raw: dict, source: str) -> tuple[float, ...]:
    lo = _number(source, "protocol.sE_min", raw.get("sE_min", 0.30))
    hi = _number(source, "protocol.sE_max", raw.get("sE_max", 1.00))
    step = _number(source, "protocol.sE_step", raw.get("sE_step", 0.05))
    if step <= 0:
        raise ConfigError(source, "protocol.sE_step", step, "a step > 0")
    if hi < lo:
        raise ConfigError(source, "protocol.sE_max", hi, f"sE_max >= sE_min ({lo:g})")
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    return tuple(round(lo + k * step, 10) for k in range(n))


# -- validation -----------------------------------------------------------------------
def validate(cfg: Config) -> None:
    """Check every value of ``cfg``; raise :class:`ConfigError` on the first bad one."""
    src = cfg.source
    if not isinstance(cfg.participant, str) or not PARTICIPANT_PATTERN.match(cfg.participant):
        raise ConfigError(src, "participant", cfg.participant,
                          "1 to 64 letters, digits, '_' or '-' (a code, never a name)")
    if cfg.seed is not None and (isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int)
                                 or cfg.seed < 0):
        raise ConfigError(src, "seed", cfg.seed, "a whole number >= 0")
    if cfg.participant_model not in PARTICIPANT_MODELS:
        raise ConfigError(src, "participant.model", cfg.participant_model,
                          "one of " + ", ".join(repr(m) for m in PARTICIPANT_MODELS))
    _validate_protocol(cfg.protocol, src)
    _validate_calibration(cfg.calibration, src)
    _validate_interlock(cfg.interlock, src)


def _positive(src, setting, value, *, allow_zero=False):
    ok = value >= 0 if allow_zero else value > 0
    if not (isinstance(value, (int, float)) and math.isfinite(value) and ok):
        raise ConfigError(src, setting, value, "a finite number " + (">= 0" if allow_zero
                                                                      else "> 0"))


def _validate_protocol(p: ProtocolConfig, src: str) -> None:
    if not p.sE_levels:
        raise ConfigError(src, "protocol.sE_levels", list(p.sE_levels),
                          "a non-empty list of numbers in (0, 1]")
    for v in p.sE_levels:
        if not (0 < v <= 1):
            raise ConfigError(src, "protocol.sE_levels", v,
                              "every sE must lie in (0, 1] (sE = Ie + If, normalised)")
    if len(set(round(v, 9) for v in p.sE_levels)) != len(p.sE_levels):
        raise ConfigError(src, "protocol.sE_levels", list(p.sE_levels),
                          "each sE level once (use repeats for repetitions)")
    if isinstance(p.repeats, bool) or not isinstance(p.repeats, int) or not 1 <= p.repeats <= 100:
        raise ConfigError(src, "protocol.repeats", p.repeats, "a whole number from 1 to 100")
    if not isinstance(p.randomisation, Randomisation):
        raise ConfigError(src, "protocol.randomisation", p.randomisation,
                          "'blocks' or 'full'")
    if not isinstance(p.pause_policy, PausePolicy):
        raise ConfigError(src, "protocol.pause_policy", p.pause_policy, "'finish' or 'abort'")
    _positive(src, "protocol.steady_s", p.steady_s, allow_zero=True)
    _positive(src, "protocol.chirp_s", p.chirp_s)
    _positive(src, "protocol.fs_Hz", p.fs_Hz)
    _positive(src, "protocol.carrier_Hz", p.carrier_Hz)
    _positive(src, "protocol.rest_s", p.rest_s, allow_zero=True)
    _positive(src, "protocol.chirp_f0_Hz", p.chirp_f0_Hz)
    _positive(src, "protocol.chirp_f1_Hz", p.chirp_f1_Hz)
    if p.chirp_f1_Hz <= p.chirp_f0_Hz:
        raise ConfigError(src, "protocol.chirp_f1_Hz", p.chirp_f1_Hz,
                          f"above chirp_f0_Hz ({p.chirp_f0_Hz:g} Hz): the chirp rises")
    nyquist = p.fs_Hz / 2
    if p.chirp_f1_Hz >= nyquist:
        raise ConfigError(src, "protocol.chirp_f1_Hz", p.chirp_f1_Hz,
                          f"below the Nyquist rate fs_Hz/2 = {nyquist:g} Hz")
    if p.trial_s * p.fs_Hz < 10:
        raise ConfigError(src, "protocol.chirp_s", p.chirp_s,
                          "a trial of at least 10 samples (steady_s + chirp_s) * fs_Hz")
    if p.trial_s > 3600:
        raise ConfigError(src, "protocol.chirp_s", p.chirp_s,
                          "steady_s + chirp_s of at most 3600 s")
    for name in ("rE_centre", "rE_amplitude"):
        v = getattr(p, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise ConfigError(src, f"protocol.{name}", v, "a finite number")
    if not isinstance(p.input_kind, InputKind):
        raise ConfigError(src, "protocol.input_kind", p.input_kind, "'chirp' or 'multisine'")
    if isinstance(p.multisine_tones, bool) or not isinstance(p.multisine_tones, int) or \
            not 2 <= p.multisine_tones <= 1000:
        raise ConfigError(src, "protocol.multisine_tones", p.multisine_tones,
                          "a whole number from 2 to 1000")
    if p.input_kind is InputKind.MULTISINE:
        # tones are harmonics of 1 / chirp_s inside the band: there must be enough of them
        available = (math.floor(p.chirp_f1_Hz * p.chirp_s + 1e-9)
                     - math.ceil(p.chirp_f0_Hz * p.chirp_s - 1e-9) + 1)
        if available < p.multisine_tones:
            raise ConfigError(src, "protocol.multisine_tones", p.multisine_tones,
                              f"at most {max(available, 0)}: the tones are multiples of "
                              f"1/chirp_s = {1 / p.chirp_s:g} Hz inside [{p.chirp_f0_Hz:g}, "
                              f"{p.chirp_f1_Hz:g}] Hz (lengthen chirp_s or widen the band)")
    if p.rE_amplitude < 0:
        raise ConfigError(src, "protocol.rE_amplitude", p.rE_amplitude, "a number >= 0")
    if p.rE_centre - p.rE_amplitude < -1e-12 or p.rE_centre + p.rE_amplitude > 1 + 1e-12:
        raise ConfigError(src, "protocol.rE_amplitude", p.rE_amplitude,
                          f"rE_centre +/- rE_amplitude inside [0, 1] (rE_centre = "
                          f"{p.rE_centre:g})")


def _validate_calibration(c: CalibrationConfig, src: str) -> None:
    _positive(src, "calibration.step_mA", c.step_mA)
    _positive(src, "calibration.hold_s", c.hold_s)
    _positive(src, "calibration.baseline_s", c.baseline_s)
    _positive(src, "calibration.rest_s", c.rest_s, allow_zero=True)
    if not 0 <= c.settle_fraction < 1:
        raise ConfigError(src, "calibration.settle_fraction", c.settle_fraction,
                          "a fraction in [0, 1)")
    _positive(src, "calibration.Fmin_N", c.Fmin_N)
    _positive(src, "calibration.Fmax_N", c.Fmax_N)
    if c.Fmax_N <= c.Fmin_N:
        raise ConfigError(src, "calibration.Fmax_N", c.Fmax_N,
                          f"above Fmin_N ({c.Fmin_N:g} N)")
    _positive(src, "calibration.force_ceiling_N", c.force_ceiling_N)
    if c.force_ceiling_N <= c.Fmax_N:
        raise ConfigError(src, "calibration.force_ceiling_N", c.force_ceiling_N,
                          f"above Fmax_N ({c.Fmax_N:g} N), or the ramp could never reach Fmax")
    _positive(src, "calibration.ceiling_ext_mA", c.ceiling_ext_mA)
    _positive(src, "calibration.ceiling_flex_mA", c.ceiling_flex_mA)
    for name, ceiling in (("ceiling_ext_mA", c.ceiling_ext_mA),
                          ("ceiling_flex_mA", c.ceiling_flex_mA)):
        if ceiling < c.step_mA:
            raise ConfigError(src, f"calibration.{name}", ceiling,
                              f"at least one ramp step ({c.step_mA:g} mA)")
    if not isinstance(c.confirm, bool):
        raise ConfigError(src, "calibration.confirm", c.confirm, "true or false")
    m = c.manual
    if m is not None:
        for name in ("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA"):
            _positive(src, f"calibration.manual.{name}", getattr(m, name), allow_zero=True)
        if not m.Iemax_mA > m.Iemin_mA:
            raise ConfigError(src, "calibration.manual.Iemax_mA", m.Iemax_mA,
                              f"above Iemin_mA ({m.Iemin_mA:g} mA)")
        if not m.Ifmax_mA > m.Ifmin_mA:
            raise ConfigError(src, "calibration.manual.Ifmax_mA", m.Ifmax_mA,
                              f"above Ifmin_mA ({m.Ifmin_mA:g} mA)")
        if m.Iemax_mA > c.ceiling_ext_mA:
            raise ConfigError(src, "calibration.manual.Iemax_mA", m.Iemax_mA,
                              f"at most calibration.ceiling_ext_mA ({c.ceiling_ext_mA:g} mA)")
        if m.Ifmax_mA > c.ceiling_flex_mA:
            raise ConfigError(src, "calibration.manual.Ifmax_mA", m.Ifmax_mA,
                              f"at most calibration.ceiling_flex_mA ({c.ceiling_flex_mA:g} mA)")


def _validate_interlock(i: InterlockConfig, src: str) -> None:
    _positive(src, "interlock.force_limit_N", i.force_limit_N)
    _positive(src, "interlock.stall_timeout_s", i.stall_timeout_s)
    if i.stall_timeout_s > 10:
        raise ConfigError(src, "interlock.stall_timeout_s", i.stall_timeout_s,
                          "at most 10 s (a stalled sensor must stop stimulation quickly)")
    _positive(src, "interlock.estop_poll_Hz", i.estop_poll_Hz)
    if i.estop_poll_Hz < 100:
        raise ConfigError(src, "interlock.estop_poll_Hz", i.estop_poll_Hz,
                          "at least 100 Hz (the switch must be seen within 10 ms)")
    for name in ("trip_on_overrun", "trip_on_over_range", "trip_on_sensor_fault"):
        if not isinstance(getattr(i, name), bool):
            raise ConfigError(src, f"interlock.{name}", getattr(i, name), "true or false")
