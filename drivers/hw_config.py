"""The hardware configuration file (TOML): which devices, channels, calibration, ceilings.

Every table is a settings model of the shared layer (:mod:`nmsid.protocols.settings_base`):
typed keys with their bounds and reasons next to them, unknown keys refused, checked
before any device is touched. A bad setting raises
:class:`~nmsid.drivers.errors.HardwareConfigError` naming the file, the dotted key, the value
and what would be valid. ``docs/hw-config.example.toml`` is a complete example;
``docs/hardware.md`` explains each table, ``docs/settings.md`` lists every key.

A new hardware setting: add a field (with ``bounded(..., why=...)`` if it has limits) to
the table's class below, and read it where the device is made (``drivers.hardware``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal, TypeAlias

from pydantic import Field, StrictBool, StrictFloat, StrictInt, StrictStr, model_validator

from nmsid.drivers.analog_force import AXES, SENSOR_SPAN_V, AnalogCalibration
from nmsid.drivers.dynamometer import DYNAMOMETER_SPAN_V, DynamometerCalibration
from nmsid.drivers.errors import HardwareConfigError, hw_config_error
from nmsid.drivers.p24_settings import P24Config
from nmsid.drivers.registry import (
    ACQUISITIONS,
    DEFAULT_STIMULATOR,
    ESTOPS,
    STIMULATORS,
    acquisition_entry,
)
from nmsid.drivers.rehamove3_settings import Rehamove3Config
from nmsid.drivers.rehastim2_settings import Rehastim2Config
from nmsid.drivers.stg4002_settings import Stg4002Config
from nmsid.protocols.settings_base import (
    SettingProblem,
    bounded,
    read_toml,
    settings_dataclass,
    validate_settings,
)

StimulatorSettings: TypeAlias = Stg4002Config | Rehastim2Config | P24Config | Rehamove3Config
"""A validated ``[stimulator]`` table, typed by its kind (the registry's settings models)."""

Axis = Literal["Fx", "Fy", "Fz", "Mx", "My", "Mz"]
"""``drivers.analog_force.AXES``; the choices of caio/nidaq below are the drivers' tables
(``RANGES_V``, ``INPUT_METHODS``, ``TERMINAL_CONFIGS``): tests/drivers/test_hw_config.py
checks they agree."""
Channel = Annotated[StrictInt, Field(ge=0, le=63, description="an A/D channel 0 .. 63")]
Positive = Annotated[StrictFloat, Field(gt=0.0, le=1e6, description="a positive rating")]
Volts = Annotated[StrictFloat, Field(ge=-100.0, le=100.0, description="a voltage within 100 V")]


@settings_dataclass(hw_config_error, prefix="rig")
class RigSettings:
    """``[rig]``: name and the fake-device switch."""

    name: StrictStr = ""
    fake: StrictBool = False
    fake_speed: StrictFloat = bounded(1.0, ge=0.1, le=100.0, why=(
        "the fakes' clock runs 0.1 .. 100 x real time"))


@settings_dataclass(hw_config_error, prefix="acquisition.caio")
class CaioSettings:
    """``[acquisition.caio]``: the Contec AI-1608AY-USB."""

    device_name: StrictStr = "AIO000"
    range: Literal["PM10", "PM5", "PM25", "PM125", "PM1"] = "PM10"
    input_method: Literal["", "single_ended", "differential"] = ""
    library: StrictStr = ""
    conversion_us: StrictFloat = bounded(10.0, ge=0.5, le=1000.0, why=(
        "the A/D's conversion time per channel in us (AI-1608AY-USB data sheet: 10); the "
        "sampling clock must be at least channels x this (Contec: 'sampling clock period "
        "error')"))


@settings_dataclass(hw_config_error, prefix="acquisition.nidaq")
class NidaqSettings:
    """``[acquisition.nidaq]``: an NI DAQ device."""

    device: StrictStr = "Dev1"
    start_trigger: StrictStr = ""
    """The sync's terminal; "" = the device's own ``/<device>/PFI0`` (drivers.nidaq)."""
    terminal_config: Literal["DEFAULT", "RSE", "NRSE", "DIFF", "PSEUDO_DIFF"] = "DIFF"
    range_V: StrictFloat = bounded(10.0, gt=0.0, le=100.0, why="an input range of NI DAQs")
    reads_per_s: StrictFloat = bounded(10.0, ge=1.0, le=100.0, why="expected 1 .. 100")


@settings_dataclass(hw_config_error, prefix="acquisition.leptrino")
class LeptrinoSettings:
    """``[acquisition.leptrino]``: the Leptrino USB sensor."""

    port: StrictStr = ""
    baudrate: StrictInt = bounded(460800, ge=1200, le=10_000_000, why="a serial baud rate")
    sync_on_external_input: StrictBool = False
    """Refused when true: the specification (v1.13, 6.1) defines no external-input bit."""

    @model_validator(mode="after")
    def _no_external_input(self):
        if self.sync_on_external_input:
            raise SettingProblem("sync_on_external_input", True,
                                 "false: the Leptrino specification v1.13, 6.1 defines no "
                                 "external-input bit (status bits 3-7 are reserved and "
                                 "undefined), so no trial can start on it; onset is aligned "
                                 "by host timing")
        return self


@settings_dataclass(hw_config_error, prefix="acquisition")
class AcquisitionSettings:
    """``[acquisition]``: which A/D chain and its rate."""

    kind: Literal["caio", "nidaq", "leptrino"] = "caio"
    fs_Hz: StrictFloat = bounded(2000.0, gt=0.0, le=100_000.0, why=(
        "the A/D chains of this rig sample at up to 100 kHz"))
    caio: CaioSettings = Field(default_factory=CaioSettings)
    nidaq: NidaqSettings = Field(default_factory=NidaqSettings)
    leptrino: LeptrinoSettings = Field(default_factory=LeptrinoSettings)
    monitor_channel: StrictInt = bounded(-1, ge=-1, le=63, why=(
        "the spare A/D input wired across the dry run's dummy-load resistor (0 .. 63; -1: "
        "none wired). Read only by nmsid probe --dry-run, never during a session"))
    monitor_fs_Hz: StrictFloat = bounded(10_000.0, ge=10_000.0, le=100_000.0, why=(
        "the dry run's sampling rate: a whole multiple of the 1 kHz carrier, at least 10 "
        "samples per carrier period (10000 .. 100000 Hz)"))

    @model_validator(mode="after")
    def _chain(self):
        per = self.monitor_fs_Hz / 1000.0
        if abs(per - round(per)) > 1e-9:
            raise SettingProblem("monitor_fs_Hz", self.monitor_fs_Hz,
                                 "a whole multiple of the 1000 Hz carrier (10000, 20000, ...)")
        problem = acquisition_entry(self.kind).check(self)
        if problem:
            raise SettingProblem(*problem)
        return self


def _analog_kinds() -> list[str]:
    return [k for k, e in ACQUISITIONS.items() if e.analog]


_ANALOG_ONLY = ("channels", "rated", "rated_output_V", "offset_V", "matrix", "sync_channel")


@settings_dataclass(hw_config_error, prefix="sensor.dynamometer")
class DynamometerSettings:
    """``[sensor.dynamometer]``: a dynamometer's analog torque output (``sensor.kind =
    "dynamometer"``; :mod:`nmsid.drivers.dynamometer`)."""

    channel: StrictInt = bounded(-1, ge=-1, le=63, why=(
        "the A/D channel of the dynamometer's torque output (0 .. 63); required with "
        "sensor.kind = dynamometer"))
    Nm_per_V: StrictFloat = bounded(0.0, ge=0.0, le=10_000.0, why=(
        "the torque output's scale as the dynamometer is set (N m per V, > 0); required "
        "with sensor.kind = dynamometer"))
    offset_V: Volts = 0.0
    """Nominal output at no torque; the automatic tare measures the real one at rest."""
    sign: Literal[1, -1] = 1
    """+1: the dynamometer's positive torque is the joint's positive direction."""
    output_span_V: tuple[StrictFloat, StrictFloat] = DYNAMOMETER_SPAN_V
    """The torque output's span, over-range at its edges (Biodex: -5 .. +5 V)."""


@settings_dataclass(hw_config_error, prefix="sensor")
class SensorSettings:
    """``[sensor]``: the force sensor, and for analog chains its wiring and calibration."""

    kind: Literal["six_axis", "dynamometer"] = "six_axis"
    """``six_axis``: the Leptrino sensor (its USB port, or its analog outputs on the A/D);
    ``dynamometer``: a dynamometer's analog torque output on the A/D (knee, ankle)."""
    model: StrictStr = "PFS080YA501G6"
    extension_direction: tuple[StrictFloat, StrictFloat, StrictFloat] = (1.0, 0.0, 0.0)
    channels: dict[Axis, Channel] = Field(default_factory=dict)
    rated: dict[Axis, Positive] = Field(default_factory=dict)
    rated_output_V: dict[Axis, Annotated[StrictFloat, Field(gt=0.0, le=100.0)]] = Field(
        default_factory=dict)
    offset_V: dict[Axis, Volts] = Field(default_factory=dict)
    matrix: tuple[tuple[StrictFloat, ...], ...] | None = None
    sync_channel: StrictInt = bounded(-1, ge=-1, le=63, why=(
        "the A/D channel of the stimulator's sync output (0 .. 63); required for analog "
        "chains"))
    output_span_V: tuple[StrictFloat, StrictFloat] = SENSOR_SPAN_V
    """The sensor's analog output span, over-range at its edges (Leptrino manual 4.1:
    0 .. 3.3 V); set another span only if an amplifier sits between sensor and A/D."""
    dynamometer: DynamometerSettings = Field(default_factory=DynamometerSettings)

    @model_validator(mode="after")
    def _direction(self):
        if not any(self.extension_direction):
            raise SettingProblem("extension_direction", list(self.extension_direction),
                                 "expected 3 numbers, not all zero (the extension axis in "
                                 "the sensor frame)")
        return self


@settings_dataclass(hw_config_error, prefix="estop")
class EStopConfig:
    """``[estop]``: the hardware E-stop switch."""

    kind: Literal["none", "serial", "nidaq"] = "none"
    port: StrictStr = ""
    line: StrictStr = "CTS"
    released_level: StrictBool = True

    @model_validator(mode="after")
    def _wired(self):
        problem = ESTOPS[self.kind].check(self)
        if problem:
            raise SettingProblem(*problem)
        return self


@settings_dataclass(hw_config_error)
class HardwareFile:
    """The whole hardware file; cross-table rules (analog wiring) live here."""

    rig: RigSettings = Field(default_factory=RigSettings)
    stimulator: Stg4002Config = Field(default_factory=Stg4002Config)
    """The default kind's table, for docs/settings.md; a file's ``[stimulator]`` is
    validated on its own by the settings model of its ``kind`` (the registry's entry)."""
    acquisition: AcquisitionSettings = Field(default_factory=AcquisitionSettings)
    sensor: SensorSettings = Field(default_factory=SensorSettings)
    estop: EStopConfig = Field(default_factory=EStopConfig)

    @model_validator(mode="after")
    def _estop_pin(self):
        problem = acquisition_entry(self.acquisition.kind).check_file(self.acquisition,
                                                                       self.estop)
        if problem:
            raise SettingProblem(*problem)
        return self

    @model_validator(mode="after")
    def _wiring(self):
        se = self.sensor
        entry = acquisition_entry(self.acquisition.kind)
        if se.kind == "dynamometer":
            return self._dynamometer_wiring(entry)
        if not entry.analog:
            analog = " or ".join(_analog_kinds())
            if self.acquisition.monitor_channel >= 0:
                raise SettingProblem("acquisition.monitor_channel",
                                     self.acquisition.monitor_channel,
                                     f"only for analog chains (acquisition.kind {analog}): "
                                     f"the {entry.title} sensor has no spare analog input")
            for key in _ANALOG_ONLY:
                value = getattr(se, key)
                if value not in ({}, None, -1):
                    raise SettingProblem(f"sensor.{key}", value, "only for analog chains "
                                         f"(acquisition.kind {analog}); the {entry.title} "
                                         "sensor reports its own rated values")
            return self
        if not se.channels:
            raise SettingProblem("sensor.channels", {}, "map the sensor's outputs to A/D "
                                 "channels, e.g. [sensor.channels] Fx = 0")
        if se.sync_channel < 0:
            raise SettingProblem("sensor.sync_channel", "(missing)", "sensor.sync_channel is "
                                 "missing; wire the stimulator's sync output to an A/D "
                                 "channel and name it (it is recorded with every trial)")
        seen: dict[int, str] = {}
        monitor = [("monitor_channel", self.acquisition.monitor_channel)] \
            if self.acquisition.monitor_channel >= 0 else []
        keys = {"sync_channel": "sensor.sync_channel",
                "monitor_channel": "acquisition.monitor_channel"}
        for axis, ch in [*se.channels.items(), ("sync_channel", se.sync_channel), *monitor]:
            if ch in seen:
                key = keys.get(axis, f"sensor.channels.{axis}")
                raise SettingProblem(key, ch, f"A/D channels must be distinct ({seen[ch]} "
                                     f"uses {ch})")
            seen[ch] = axis
        if not any(a in se.channels for a in AXES[:3]):
            raise SettingProblem("sensor.channels", dict(se.channels),
                                 "at least one force axis (Fx, Fy, Fz) wired to the A/D")
        for i, axis in enumerate(AXES[:3]):
            if se.extension_direction[i] != 0 and axis not in se.channels:
                raise SettingProblem("sensor.extension_direction", list(se.extension_direction),
                                     f"uses {axis}, which is not wired to the A/D")
        if se.matrix is not None:
            if len(se.matrix) != 6 or any(len(row) != 6 for row in se.matrix):
                raise SettingProblem("sensor.matrix", "...", "6 rows of 6 numbers")
            if set(se.channels) != set(AXES):
                raise SettingProblem("sensor.matrix", "...",
                                     "a 6 x 6 matrix needs all six axes wired to the A/D")
        else:
            for axis in se.channels:
                for key in ("rated", "rated_output_V"):
                    if axis not in getattr(se, key):
                        raise SettingProblem(f"sensor.{key}.{axis}", "(missing)",
                                             f"axis {axis}: rated and rated_output_V must "
                                             "both be > 0")
        return self

    def _dynamometer_wiring(self, entry):
        """``sensor.kind = "dynamometer"``: one torque output and the sync on an analog
        chain; the six-axis sensor's keys are refused (one sensor per rig)."""
        se, dy = self.sensor, self.sensor.dynamometer
        analog = " or ".join(_analog_kinds())
        if not entry.analog:
            raise SettingProblem("sensor.kind", se.kind, "a dynamometer's analog torque "
                                 f"output needs an analog chain (acquisition.kind {analog}); "
                                 f"the {entry.title} is the six-axis sensor's own port")
        for key in ("channels", "rated", "rated_output_V", "offset_V", "matrix"):
            value = getattr(se, key)
            if value not in ({}, None):
                raise SettingProblem(f"sensor.{key}", value, "the six-axis sensor's; with "
                                     "sensor.kind = dynamometer give [sensor.dynamometer] "
                                     "channel, Nm_per_V, offset_V, sign instead")
        if dy.channel < 0:
            raise SettingProblem("sensor.dynamometer.channel", "(missing)", "the A/D channel "
                                 "of the dynamometer's torque output (0 .. 63)")
        if not dy.Nm_per_V > 0:
            raise SettingProblem("sensor.dynamometer.Nm_per_V", "(missing)", "the torque "
                                 "output's scale in N m per V, as the dynamometer is set "
                                 "(> 0)")
        lo, hi = dy.output_span_V
        if not lo < hi:
            raise SettingProblem("sensor.dynamometer.output_span_V", list(dy.output_span_V),
                                 "two volts, low < high")
        if se.sync_channel < 0:
            raise SettingProblem("sensor.sync_channel", "(missing)", "sensor.sync_channel is "
                                 "missing; wire the stimulator's sync output to an A/D "
                                 "channel and name it (it is recorded with every trial)")
        seen: dict[int, str] = {}
        monitor = self.acquisition.monitor_channel
        for key, ch in [("sensor.dynamometer.channel", dy.channel),
                        ("sensor.sync_channel", se.sync_channel),
                        *([("acquisition.monitor_channel", monitor)] if monitor >= 0 else [])]:
            if ch in seen:
                raise SettingProblem(key, ch, f"A/D channels must be distinct ({seen[ch]} "
                                     f"uses {ch})")
            seen[ch] = key
        return self


@dataclass(frozen=True)
class AcquisitionConfig:
    """The A/D chain as ``drivers.hardware`` uses it (built from :class:`AcquisitionSettings`)."""

    kind: str = "caio"
    fs_Hz: float = 2000.0
    monitor_channel: int | None = None
    """The dry run's resistor monitor input (None: not wired)."""
    monitor_fs_Hz: float = 10_000.0
    caio: dict = field(default_factory=dict)
    nidaq: dict = field(default_factory=dict)
    leptrino: dict = field(default_factory=dict)


@dataclass(frozen=True)
class HardwareConfig:
    """A validated hardware file, as ``drivers.hardware.make_hw_rig`` uses it."""

    source: str
    name: str
    fake: bool
    fake_speed: float
    stimulator: StimulatorSettings
    """Typed by ``kind``; :mod:`nmsid.drivers.registry` knows what each kind needs."""
    acquisition: AcquisitionConfig
    calibration: AnalogCalibration | DynamometerCalibration | None
    """Analog chains only (``analog`` in the acquisition kind's registry entry): the
    six-axis sensor's analog outputs, or a dynamometer's torque output."""
    extension_direction: tuple[float, float, float]
    sensor_model: str
    estop: EStopConfig

    def describe(self) -> str:
        acq = acquisition_entry(self.acquisition.kind).title
        text = f"hw: {STIMULATORS[self.stimulator.kind].title} + {acq} ({self.sensor_model})"
        return text + (" [FAKE devices]" if self.fake else "")


def load_hw_config(path) -> HardwareConfig:
    """Read and validate a hardware configuration file.

    Raises
    ------
    HardwareConfigError
        Naming the file and the setting.
    FileNotFoundError
        If the file does not exist.
    """
    data = read_toml(path, hw_config_error, what="hardware configuration (--hw-config)")
    return parse_hw_config(data, str(path))


def parse_hw_config(data: dict, source: str = "<hw config>") -> HardwareConfig:
    """Validate a hardware file's tables (``load_hw_config`` without the reading)."""
    stimulator: StimulatorSettings = Stg4002Config()
    if isinstance(data, dict) and "stimulator" in data:
        # the [stimulator] table on its own, by its kind: messages name "stimulator.<key>"
        stimulator = _stimulator_settings(data["stimulator"], source)
        data = {k: v for k, v in data.items() if k != "stimulator"}
    f = validate_settings(HardwareFile, data, source=source, make_error=hw_config_error)
    a, se = f.acquisition, f.sensor
    acq = AcquisitionConfig(
        kind=a.kind, fs_Hz=a.fs_Hz,
        monitor_channel=a.monitor_channel if a.monitor_channel >= 0 else None,
        monitor_fs_Hz=a.monitor_fs_Hz,
        caio={"device_name": a.caio.device_name, "ai_range": a.caio.range,
              "input_method": a.caio.input_method, "library": a.caio.library,
              "conversion_us": a.caio.conversion_us},
        nidaq={"device": a.nidaq.device, "start_trigger": a.nidaq.start_trigger,
               "terminal_config": a.nidaq.terminal_config, "range_V": a.nidaq.range_V,
               "reads_per_s": a.nidaq.reads_per_s},
        leptrino={"port": a.leptrino.port, "baudrate": a.leptrino.baudrate,
                  "sync_on_external_input": a.leptrino.sync_on_external_input})
    cal: AnalogCalibration | DynamometerCalibration | None = None
    if se.kind == "dynamometer":
        dy = se.dynamometer
        cal = DynamometerCalibration(channel=dy.channel, Nm_per_V=dy.Nm_per_V,
                                     offset_V=dy.offset_V, sign=float(dy.sign),
                                     sync_channel=se.sync_channel,
                                     sensor_span_V=tuple(dy.output_span_V))
    elif acquisition_entry(a.kind).analog:
        try:
            cal = AnalogCalibration(
                channels=dict(se.channels), rated=dict(se.rated),
                rated_output_V=dict(se.rated_output_V), offset_V=dict(se.offset_V),
                matrix=se.matrix, extension_direction=se.extension_direction,
                sync_channel=se.sync_channel, sensor_span_V=tuple(se.output_span_V))
        except (ValueError, TypeError) as exc:      # a rule of the driver's own
            raise HardwareConfigError(f"{source}: [sensor]: {exc}") from None
    return HardwareConfig(source=source, name=f.rig.name, fake=f.rig.fake,
                          fake_speed=f.rig.fake_speed, stimulator=stimulator,
                          acquisition=acq, calibration=cal,
                          extension_direction=se.extension_direction,
                          sensor_model="analog dynamometer" if se.kind == "dynamometer"
                          and se.model == "PFS080YA501G6" else se.model,
                          estop=f.estop)


def _stimulator_settings(table, source: str) -> StimulatorSettings:
    """``[stimulator]`` validated by the settings model of its ``kind`` (absent: the
    registry's default kind), the ``settings`` of its entry in
    :data:`nmsid.drivers.registry.STIMULATORS`."""
    if not isinstance(table, dict):
        raise hw_config_error(source, "stimulator", table, "a table of settings")
    kind = table.get("kind", DEFAULT_STIMULATOR)
    entry = STIMULATORS.get(kind) if isinstance(kind, str) else None
    if entry is None:
        raise hw_config_error(source, "stimulator.kind", kind,
                              "one of " + ", ".join(repr(k) for k in STIMULATORS))
    return validate_settings(entry.settings, table, source=source, make_error=hw_config_error,
                             prefix="stimulator")
