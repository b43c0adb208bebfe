"""One validated configuration for a session: defaults built in, overridable by a TOML file.

Layout of the TOML file (every key optional; unknown keys are refused)::

    participant = "P01"
    joint = "elbow"                # "elbow" | "knee" | "ankle" (protocols/joints.py): its
                                   # labels, unit and default limits (docs/joints.md)
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
    reference_sE = 0.6             # reference trials to track fatigue (default: none)
    reference_every = 9            # ... first, after every 9 scheduled trials, and last
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
    confirm_weakened_safety = false  # needed for a trip_on_* = false or a force_limit_N
                                   # above the sensor range (docs/settings.md)

    [lsl]                          # Lab Streaming Layer (docs/lsl.md); off by default
    publish = false                # outlets for force, currents, markers (= --lsl)
    record = []                    # streams recorded into the file, e.g. ["EMG"]
                                   # (= --lsl-record EMG, which replaces this list)

Every key is a field of a pydantic dataclass below, with its bounds and their reason next
to it (:mod:`nmsid.protocols.settings_base`); ``docs/settings.md`` lists them all.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
import re
from typing import Annotated, Any

from pydantic import AfterValidator, Field, StrictFloat, StrictInt, model_validator

from nmsid.protocols.calibration_settings import MAX_RAMP_STEPS, CalibrationConfig, ManualCurrents
from nmsid.protocols.errors import ConfigError
from nmsid.protocols.interlock_settings import (
    CONFIRM_WORDS,
    FORCE_SENSOR_RANGE_N,
    TRIP_SWITCHES,
    InterlockConfig,
)
from nmsid.protocols.joints import DEFAULT_JOINT, JOINTS, Joint
from nmsid.protocols.lsl_settings import LslConfig
from nmsid.protocols.settings_base import (
    SettingProblem,
    bounded,
    read_toml,
    replace_settings,
    settings_dataclass,
    validate_settings,
)

PARTICIPANT_PATTERN = re.compile(r"[A-Za-z0-9_-]{1,64}")
"""A participant code (used with ``fullmatch``: no trailing newline slips through)."""
PARTICIPANT_MODELS = ("template", "musculoskeletal")
"""Simulated participants ``[participant] model`` can name: the paper's second-order model
with add-on effects (``sim_backends.participant``), or MyoSuite's MuJoCo elbow under FES
(``sim_backends.msk_participant``; at the knee and the ankle MuJoCo's MyoLeg,
``sim_backends.msk_leg``). Hardware sessions ignore it."""

PLUGIN_MODEL_PATTERN = r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*"
"""A lab's own simulated participant, ``package.module:factory`` (``sim_backends.plugin``)."""

DEFAULT_SOURCE = "built-in defaults"

__all__ = ["Config", "ConfigError", "ProtocolConfig", "CalibrationConfig", "InterlockConfig",
           "ManualCurrents", "LslConfig", "Randomisation", "InputKind", "PausePolicy",
           "PARTICIPANT_MODELS",
           "PARTICIPANT_PATTERN", "MAX_LEVELS", "MAX_TRIALS", "MAX_SESSION_S",
           "MAX_TRIAL_SAMPLES", "MAX_RAMP_STEPS", "SEED_MAX", "FORCE_SENSOR_RANGE_N",
           "TRIP_SWITCHES", "load_config", "config_from_json", "config_from_dict", "validate"]

MAX_LEVELS = 100
"""At most this many sE levels (the paper: 15); 1/100 of the sE range is below the
resolution a force recording can tell apart."""
MAX_TRIALS = 2000
"""Levels x repeats at most (the paper: 45)."""
MAX_SESSION_S = 12 * 3600.0
"""Total stimulation + rest time of a schedule at most (the paper's: about 56 min)."""
MAX_TRIAL_SAMPLES = 20_000_000
"""(steady_s + chirp_s) x fs_Hz at most: one trial's arrays stay below ~1 GB."""
SEED_MAX = 2 ** 63 - 1
"""Largest seed: numpy's generators take any integer >= 0, but the session file stores
the seed as a 64-bit signed integer."""
def _participant_code(value: str) -> str:
    if not PARTICIPANT_PATTERN.fullmatch(value):
        raise SettingProblem("", value, "1 to 64 letters, digits, '_' or '-' (a code, never "
                             "a name; no spaces or control characters)")
    return value


Fraction = Annotated[StrictFloat, Field(ge=0.0, le=1.0)]
SELevel = Annotated[StrictFloat, Field(gt=0.0, le=1.0)]


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


def _problem(source, key, value, valid) -> SettingProblem:
    return SettingProblem(key, value, valid)


@settings_dataclass(ConfigError, prefix="protocol")
class LevelRange:
    """``sE_min`` / ``sE_max`` / ``sE_step``: the levels as a range (instead of sE_levels)."""

    sE_min: StrictFloat = bounded(0.30, gt=0.0, le=1.0, why="sE = Ie + If, normalised")
    sE_max: StrictFloat = bounded(1.00, gt=0.0, le=1.0, why="sE = Ie + If, normalised")
    sE_step: StrictFloat = bounded(0.05, gt=0.0, le=1.0, why="a step of sE")


@settings_dataclass(ConfigError, prefix="protocol")
class ProtocolConfig:
    """The identification protocol (paper: 15 sE x 3 repeats, 5 s steady + 10 s chirp).

    In a file, ``sE_min`` / ``sE_max`` / ``sE_step`` may replace ``sE_levels``.
    """

    sE_levels: tuple[SELevel, ...] = bounded(
        default_factory=_default_levels, min_length=1, max_length=MAX_LEVELS,
        why=f"at most {MAX_LEVELS} levels, each in (0, 1] (sE = Ie + If, normalised)")
    repeats: StrictInt = bounded(3, ge=1, le=100, why="a whole number of repeats per sE")
    randomisation: Randomisation = Randomisation.BLOCKS
    steady_s: StrictFloat = bounded(5.0, ge=0.0, le=600.0, why=(
        "a steady lead-in of at most 10 min; the paper: 5 s"))
    chirp_s: StrictFloat = bounded(10.0, gt=0.0, le=3600.0, why=(
        "an excitation of at most an hour; the paper: 10 s"))
    chirp_f0_Hz: StrictFloat = bounded(1.0, gt=0.0, le=1000.0, why=(
        "muscle dynamics lie below a few tens of Hz"))
    chirp_f1_Hz: StrictFloat = bounded(10.0, gt=0.0, le=1000.0, why=(
        "muscle dynamics lie below a few tens of Hz"))
    rE_centre: Fraction = 0.5
    rE_amplitude: Fraction = 0.5
    fs_Hz: StrictFloat = bounded(2000.0, ge=10.0, le=100_000.0, why=(
        "the acquisition chains sample between 10 Hz and 100 kHz; the paper: 2 kHz"))
    carrier_Hz: StrictFloat = bounded(1000.0, gt=0.0, le=100_000.0, why=(
        "the STG4002 renders carriers up to a few tens of kHz; the paper: 1 kHz"))
    rest_s: StrictFloat = bounded(60.0, ge=0.0, le=3600.0, why=(
        "a rest of at most an hour between trials; the paper: 60 s"))
    pause_policy: PausePolicy = PausePolicy.FINISH
    input_kind: InputKind = InputKind.CHIRP
    multisine_tones: StrictInt = bounded(24, ge=2, le=1000, why="tones of a multisine")
    reference_sE: SELevel | None = None
    """Reference trials (off by default): a trial at this sE first, after every
    ``reference_every`` scheduled trials, and last, so fatigue is tracked at one fixed sE
    (``docs/identification.md``)."""
    reference_every: StrictInt = bounded(0, ge=0, le=MAX_TRIALS, why=(
        "scheduled trials between two reference trials (0: none)"))

    @model_validator(mode="before")
    @classmethod
    def _levels_from_range(cls, data):
        if not isinstance(data, dict) or not any(k in data for k in _LEVEL_RANGE_KEYS):
            return data
        if "sE_levels" in data:
            raise SettingProblem("sE_levels", data["sE_levels"],
                                 "give either sE_levels or sE_min/sE_max/sE_step, not both")
        data = dict(data)
        given = {k: data.pop(k) for k in _LEVEL_RANGE_KEYS if k in data}
        r = validate_settings(LevelRange, given, source="", make_error=_problem)
        lo, hi, step = r.sE_min, r.sE_max, r.sE_step
        if not lo <= hi <= 1:
            raise SettingProblem("sE_max", hi, f"in [sE_min, 1] = [{lo:g}, 1]")
        n = math.floor((hi - lo) / step + 1e-9) + 1
        if n > MAX_LEVELS:
            raise SettingProblem("sE_step", step,
                                 f"at least (sE_max - sE_min) / {MAX_LEVELS - 1} = "
                                 f"{(hi - lo) / (MAX_LEVELS - 1):.3g}: at most {MAX_LEVELS} "
                                 "levels")
        data["sE_levels"] = tuple(round(lo + k * step, 10) for k in range(n))
        return data

    @model_validator(mode="after")
    def _consistent(self):
        if len({round(v, 9) for v in self.sE_levels}) != len(self.sE_levels):
            raise SettingProblem("sE_levels", list(self.sE_levels),
                                 "each sE level once (use repeats for repetitions)")
        if (self.reference_sE is None) != (self.reference_every == 0):
            raise SettingProblem("reference_every", self.reference_every,
                                 "reference trials need both reference_sE (in (0, 1]) and "
                                 "reference_every >= 1; give neither for none")
        n_trials = self.n_trials
        if n_trials > MAX_TRIALS:
            raise SettingProblem("repeats", self.repeats,
                                 f"at most {MAX_TRIALS} trials in all (levels x repeats = "
                                 f"{n_trials})")
        if self.chirp_f1_Hz <= self.chirp_f0_Hz:
            raise SettingProblem("chirp_f1_Hz", self.chirp_f1_Hz,
                                 f"above chirp_f0_Hz ({self.chirp_f0_Hz:g} Hz): the chirp rises")
        nyquist = self.fs_Hz / 2
        if self.chirp_f1_Hz >= nyquist:
            raise SettingProblem("chirp_f1_Hz", self.chirp_f1_Hz,
                                 f"below the Nyquist rate fs_Hz/2 = {nyquist:g} Hz")
        if self.trial_s * self.fs_Hz < 10:
            raise SettingProblem("chirp_s", self.chirp_s, "a trial of at least 10 samples "
                                 "(steady_s + chirp_s) * fs_Hz")
        if self.trial_s * self.fs_Hz > MAX_TRIAL_SAMPLES:
            raise SettingProblem("fs_Hz", self.fs_Hz,
                                 f"(steady_s + chirp_s) * fs_Hz of at most "
                                 f"{MAX_TRIAL_SAMPLES:g} samples per trial (memory)")
        session_s = n_trials * (self.trial_s + self.rest_s)
        if session_s > MAX_SESSION_S:
            raise SettingProblem("rest_s", self.rest_s,
                                 f"a schedule of at most {MAX_SESSION_S / 3600:g} h "
                                 f"(trials x (steady_s + chirp_s + rest_s) = "
                                 f"{session_s / 3600:.3g} h)")
        if self.input_kind is InputKind.MULTISINE:
            # tones are harmonics of 1 / chirp_s inside the band: there must be enough
            available = (math.floor(self.chirp_f1_Hz * self.chirp_s + 1e-9)
                         - math.ceil(self.chirp_f0_Hz * self.chirp_s - 1e-9) + 1)
            if available < self.multisine_tones:
                raise SettingProblem(
                    "multisine_tones", self.multisine_tones,
                    f"at most {max(available, 0)}: the tones are multiples of 1/chirp_s = "
                    f"{1 / self.chirp_s:g} Hz inside [{self.chirp_f0_Hz:g}, "
                    f"{self.chirp_f1_Hz:g}] Hz (lengthen chirp_s or widen the band)")
        if (self.rE_centre - self.rE_amplitude < -1e-12
                or self.rE_centre + self.rE_amplitude > 1 + 1e-12):
            raise SettingProblem("rE_amplitude", self.rE_amplitude,
                                 f"rE_centre +/- rE_amplitude inside [0, 1] (rE_centre = "
                                 f"{self.rE_centre:g})")
        return self

    @property
    def trial_s(self) -> float:
        return self.steady_s + self.chirp_s

    @property
    def n_samples(self) -> int:
        """Samples per trial."""
        return int(round(self.trial_s * self.fs_Hz))

    @property
    def n_trials(self) -> int:
        """Scheduled trials, reference trials included."""
        n = len(self.sE_levels) * self.repeats
        return n + (0 if self.reference_sE is None else -(-n // self.reference_every) + 1)

    @property
    def session_s(self) -> float:
        """Stimulation plus rest time of the whole schedule in s."""
        return self.n_trials * (self.trial_s + self.rest_s)


_LEVEL_RANGE_KEYS = ("sE_min", "sE_max", "sE_step")


@settings_dataclass(ConfigError)
class Config:
    """Everything a session needs, validated on construction (see :func:`load_config`)."""

    participant: Annotated[str, AfterValidator(_participant_code)] = "P01"
    seed: StrictInt | None = bounded(None, ge=0, le=SEED_MAX, why=(
        "the session file stores the seed as a 64-bit signed integer"))
    joint: str = DEFAULT_JOINT
    """The joint the session drives (:data:`nmsid.protocols.joints.JOINTS`): a file that
    names one and leaves ``[interlock] force_limit_N`` or ``[calibration] Fmin_N`` /
    ``Fmax_N`` / ``force_ceiling_N`` out gets that joint's defaults, in its unit.
    :meth:`replace` (``joint=...``) keeps the tables as they are: build a configuration
    of another joint with :func:`load_config` / :func:`config_from_dict` instead."""
    participant_model: str = "template"
    """Which simulated participant ``--backend sim`` puts on the rig
    (:data:`PARTICIPANT_MODELS`); TOML ``[participant] model``."""
    protocol: ProtocolConfig = Field(default_factory=ProtocolConfig)
    calibration: CalibrationConfig = Field(default_factory=CalibrationConfig)
    interlock: InterlockConfig = Field(default_factory=InterlockConfig)
    lsl: LslConfig = Field(default_factory=LslConfig)
    source: str = DEFAULT_SOURCE
    """Where the values came from (for messages); not stored."""

    @model_validator(mode="before")
    @classmethod
    def _participant_table(cls, data):
        if isinstance(data, dict) and isinstance(data.get("participant"), dict):
            data = dict(data)
            table = data.pop("participant")
            for key in table:
                if key not in ("code", "model"):
                    raise SettingProblem(f"participant.{key}", table[key],
                                         "unknown setting; known settings here are: code, "
                                         "model")
            if "code" in table:
                data["participant"] = table["code"]
            if "model" in table:
                data["participant_model"] = table["model"]
        return data

    @model_validator(mode="before")
    @classmethod
    def _joint_defaults(cls, data):
        if not isinstance(data, dict) or "joint" not in data:
            return data
        name = data["joint"]
        if not isinstance(name, str) or name not in JOINTS:
            raise SettingProblem("joint", name, "one of " + ", ".join(
                repr(j) for j in JOINTS) + " (protocols/joints.py; docs/joints.md)")
        joint = JOINTS[name]
        data = dict(data)
        for table, defaults in (("interlock", {"force_limit_N": joint.limit}),
                                ("calibration", {"Fmin_N": joint.Fmin, "Fmax_N": joint.Fmax,
                                                 "force_ceiling_N": joint.ceiling})):
            given = data.get(table, {})
            if isinstance(given, dict):     # an object built in code is kept as it is
                data[table] = {**defaults, **given}
        return data

    @model_validator(mode="after")
    def _model_known(self):
        if self.participant_model not in PARTICIPANT_MODELS and not re.fullmatch(
                PLUGIN_MODEL_PATTERN, self.participant_model):
            raise SettingProblem("participant.model", self.participant_model,
                                 "one of " + ", ".join(repr(m) for m in PARTICIPANT_MODELS)
                                 + " or a plug-in 'package.module:factory'")
        return self

    @model_validator(mode="after")
    def _limit_within_joint_sensor(self):
        # a lab's joint may have a sensor below the 6-axis sensor's 500 N the interlock's
        # own rule knows: a limit above the joint's sensor range can never trip either
        j, lim = JOINTS[self.joint], self.interlock.force_limit_N
        if lim > j.sensor_range and not self.interlock.confirm_weakened_safety:
            raise SettingProblem("interlock.force_limit_N", lim,
                                 f"at most the {j.name} sensor's range ({j.sensor_range:g} "
                                 f"{j.unit}), or {CONFIRM_WORDS}")
        return self

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
        if not d["interlock"]["confirm_weakened_safety"]:   # older readers lack the key
            del d["interlock"]["confirm_weakened_safety"]
        if d["seed"] is None:
            del d["seed"]
        if d["joint"] == DEFAULT_JOINT:    # older readers lack the key
            del d["joint"]
        if d["lsl"] == {"publish": False, "record": []}:   # older readers lack the table
            del d["lsl"]
        model = d.pop("participant_model")
        if model != "template":     # the plain string form otherwise (older readers)
            d["participant"] = {"code": d["participant"], "model": model}
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def replace(self, **changes) -> Config:
        """A copy with top-level fields changed, validated again.

        Raises
        ------
        ConfigError
            Naming the setting, as for a file.
        """
        return replace_settings(self, ConfigError, self.source, **changes)

    def with_protocol(self, **changes) -> Config:
        """A copy with protocol fields changed, validated again."""
        protocol = replace_settings(self.protocol, _prefixed(ConfigError, "protocol"),
                                    self.source, **changes)
        return self.replace(protocol=protocol)

    @property
    def joint_def(self) -> Joint:
        """The session's :class:`~nmsid.protocols.joints.Joint`."""
        return JOINTS[self.joint]

    def weakened_safety(self) -> list[str]:
        """The settings that weaken the interlock (each needs the confirmation)."""
        out = self.interlock.weakened()
        j, lim = JOINTS[self.joint], self.interlock.force_limit_N
        if j.sensor_range < lim <= FORCE_SENSOR_RANGE_N:   # above 500 N: said just above
            out.append(f"interlock.force_limit_N = {lim:g} (above the {j.name} sensor's "
                       f"range, {j.sensor_range:g} {j.unit}: it can never trip)")
        return out

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


def _prefixed(make_error, prefix: str):
    def make(source, key, value, valid):
        return make_error(source, f"{prefix}.{key}", value, valid)
    return make


# -- loading --------------------------------------------------------------------------
def load_config(path: str | os.PathLike | None = None, *, overrides: dict | None = None
                ) -> Config:
    """Load and validate a configuration.

    Parameters
    ----------
    path : path-like, optional
        A TOML file; None uses the built-in defaults.
    overrides : dict, optional
        Top-level values that win over the file (``{"participant": "P07", "seed": 3}``),
        as given on the command line; ``{"confirm_weakened_safety": True}`` sets
        ``interlock.confirm_weakened_safety`` (``--allow-weakened-safety``).

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
        data = read_toml(path, ConfigError, what=(
            "configuration file (give a TOML file with --config, or leave --config out for "
            "the built-in paper protocol)"))
    for key, value in (overrides or {}).items():
        if value is None or value is False and key == "confirm_weakened_safety":
            continue
        if key == "participant" and isinstance(data.get("participant"), dict):
            data["participant"] = {**data["participant"], "code": value}
        elif key == "confirm_weakened_safety":
            table = data.get("interlock", {})
            data["interlock"] = {**table, key: value} if isinstance(table, dict) else table
        else:
            data[key] = value
    return config_from_dict(data, source=source)


def config_from_json(text: str, source: str = "session file config_json") -> Config:
    """Rebuild a configuration stored with a session (``Config.to_json``)."""
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ConfigError(source, "config_json", text[:40], f"not valid JSON: {exc}") from None
    return config_from_dict(data, source=source)


def config_from_dict(data: dict[str, Any], *, source: str = DEFAULT_SOURCE) -> Config:
    """Build and validate a :class:`Config` from a dict with the TOML layout.

    Raises
    ------
    ConfigError
        Naming ``source``, the dotted setting, the value and what is valid.
    """
    if isinstance(data, dict) and "source" in data:
        raise ConfigError(source, "source", data["source"], "unknown setting")
    if isinstance(data, dict):
        data = {**data, "source": source}
    return validate_settings(Config, data, source=source, make_error=ConfigError)


def validate(cfg: Config) -> None:
    """Check every value of ``cfg`` again (a :class:`Config` is validated when built)."""
    config_from_dict(cfg.to_dict(), source=cfg.source)
