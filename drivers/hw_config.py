"""The hardware configuration file (TOML): which devices, channels, calibration, ceilings.

Every setting is validated before any device is touched; a bad one raises
:class:`~nmsid.drivers.errors.HardwareConfigError` naming the file, the setting (dotted path),
the value and what would be valid. Unknown settings are refused too (a typo must not
silently fall back to a default). ``docs/hw-config.example.toml`` is a complete example;
``docs/hardware.md`` explains each table.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from nmsid.drivers.analog_force import AXES, AnalogCalibration
from nmsid.drivers.caio import INPUT_METHODS, RANGES_V
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.nidaq import TERMINAL_CONFIGS

LEPTRINO_MAX_RATE_HZ = 1200.0
"""What the Leptrino USB interface streams at (vendor sample: "maximum 1.2 kHz")."""


@dataclass(frozen=True)
class StimulatorConfig:
    kind: str = "stg4002"
    dll_path: str = ""
    serial: str = ""
    extensor_channel: int = 1
    flexor_channel: int = 2
    sync_out: int = 1
    ceiling_ext_mA: float = 16.0
    ceiling_flex_mA: float = 16.0


@dataclass(frozen=True)
class AcquisitionConfig:
    kind: str = "caio"
    fs_Hz: float = 2000.0
    caio: dict = field(default_factory=dict)
    nidaq: dict = field(default_factory=dict)
    leptrino: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EStopConfig:
    kind: str = "none"
    port: str = ""
    line: str = "CTS"
    released_level: bool = True


@dataclass(frozen=True)
class HardwareConfig:
    source: str
    name: str
    fake: bool
    fake_speed: float
    stimulator: StimulatorConfig
    acquisition: AcquisitionConfig
    calibration: AnalogCalibration | None
    """Analog chains only (caio, nidaq)."""
    extension_direction: tuple[float, float, float]
    sensor_model: str
    estop: EStopConfig

    def describe(self) -> str:
        acq = {"caio": "Contec AI-1608AY-USB", "nidaq": "NI DAQ",
               "leptrino": "Leptrino USB"}[self.acquisition.kind]
        text = f"hw: MCS STG4002 + {acq} ({self.sensor_model})"
        return text + (" [FAKE devices]" if self.fake else "")


class _Reader:
    """Typed access to one TOML table that remembers which keys were used."""

    def __init__(self, source: str, table: dict, prefix: str):
        if not isinstance(table, dict):
            raise HardwareConfigError(f"{source}: [{prefix}] must be a table")
        self.source, self.table, self.prefix = source, table, prefix
        self.used: set[str] = set()

    def _name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def fail(self, key: str, value, valid: str):
        raise HardwareConfigError(f"{self.source}: {self._name(key)} = {value!r} is invalid; "
                                  f"{valid}")

    def get(self, key: str, default, kind):
        self.used.add(key)
        if key not in self.table:
            return default
        v = self.table[key]
        if kind is float:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(key, v, "expected a finite number")
            return float(v)
        if kind is int:
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(key, v, "expected a whole number")
            return v
        if kind is bool:
            if not isinstance(v, bool):
                self.fail(key, v, "expected true or false")
            return v
        if kind is str:
            if not isinstance(v, str):
                self.fail(key, v, "expected a string")
            return v
        return v

    def choice(self, key: str, default: str, choices) -> str:
        v = self.get(key, default, str)
        if v not in choices:
            self.fail(key, v, f"valid: {', '.join(sorted(choices))}")
        return v

    def table_of(self, key: str) -> "_Reader":
        self.used.add(key)
        return _Reader(self.source, self.table.get(key, {}), self._name(key))

    def done(self, allow_tables=()) -> None:
        unknown = set(self.table) - self.used - set(allow_tables)
        if unknown:
            names = ", ".join(self._name(k) for k in sorted(unknown))
            raise HardwareConfigError(f"{self.source}: unknown setting(s) {names}; see "
                                      "docs/hw-config.example.toml for the valid ones")


def load_hw_config(path) -> HardwareConfig:
    """Read and validate a hardware configuration file.

    Raises
    ------
    HardwareConfigError
        Naming the file and the setting.
    FileNotFoundError
        If the file does not exist.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"hardware configuration {p} not found (--hw-config)")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise HardwareConfigError(f"{p}: not valid TOML: {exc}") from None
    return parse_hw_config(data, str(p))


def parse_hw_config(data: dict, source: str = "<hw config>") -> HardwareConfig:
    root = _Reader(source, data, "")
    rig = root.table_of("rig")
    name = rig.get("name", "", str)
    fake = rig.get("fake", False, bool)
    speed = rig.get("fake_speed", 1.0, float)
    if not 0.1 <= speed <= 100:
        rig.fail("fake_speed", speed, "expected 0.1 .. 100")
    rig.done()

    s = root.table_of("stimulator")
    stim = StimulatorConfig(
        kind=s.choice("kind", "stg4002", {"stg4002"}),
        dll_path=s.get("dll_path", "", str), serial=s.get("serial", "", str),
        extensor_channel=s.get("extensor_channel", 1, int),
        flexor_channel=s.get("flexor_channel", 2, int), sync_out=s.get("sync_out", 1, int),
        ceiling_ext_mA=s.get("ceiling_ext_mA", 16.0, float),
        ceiling_flex_mA=s.get("ceiling_flex_mA", 16.0, float))
    for key in ("extensor_channel", "flexor_channel", "sync_out"):
        if not 1 <= getattr(stim, key) <= 8:
            s.fail(key, getattr(stim, key), "channels are numbered from 1 (1 .. 8)")
    if stim.extensor_channel == stim.flexor_channel:
        s.fail("flexor_channel", stim.flexor_channel, "must differ from extensor_channel")
    for key in ("ceiling_ext_mA", "ceiling_flex_mA"):
        if not 0 < getattr(stim, key) <= 100:
            s.fail(key, getattr(stim, key), "expected > 0 and <= 100 mA (the device's own "
                   "range is checked when it is connected)")
    s.done()

    a = root.table_of("acquisition")
    kind = a.choice("kind", "caio", {"caio", "nidaq", "leptrino"})
    fs = a.get("fs_Hz", 2000.0, float)
    if not fs > 0:
        a.fail("fs_Hz", fs, "expected > 0")
    if kind == "leptrino" and fs > LEPTRINO_MAX_RATE_HZ:
        a.fail("fs_Hz", fs, f"the Leptrino USB interface streams at about "
               f"{LEPTRINO_MAX_RATE_HZ:g} Hz and cannot give {fs:g} Hz; use an analog chain "
               "(acquisition.kind = \"caio\" or \"nidaq\") for the paper's 2000 Hz, or set "
               f"acquisition.fs_Hz (and the protocol's fs_Hz) to {LEPTRINO_MAX_RATE_HZ:g}")
    sub = {}
    c = a.table_of("caio")
    sub["caio"] = dict(device_name=c.get("device_name", "AIO000", str),
                       ai_range=c.choice("range", "PM10", set(RANGES_V)),
                       input_method=c.choice("input_method", "", set(INPUT_METHODS) | {""}),
                       library=c.get("library", "", str))
    c.done()
    n = a.table_of("nidaq")
    sub["nidaq"] = dict(device=n.get("device", "Dev1", str),
                        start_trigger=n.get("start_trigger", "/Dev1/PFI0", str),
                        terminal_config=n.choice("terminal_config", "DIFF",
                                                 set(TERMINAL_CONFIGS)),
                        range_V=n.get("range_V", 10.0, float),
                        reads_per_s=n.get("reads_per_s", 10.0, float))
    if not sub["nidaq"]["range_V"] > 0:
        n.fail("range_V", sub["nidaq"]["range_V"], "expected > 0")
    if not 1 <= sub["nidaq"]["reads_per_s"] <= 100:
        n.fail("reads_per_s", sub["nidaq"]["reads_per_s"], "expected 1 .. 100")
    n.done()
    lt = a.table_of("leptrino")
    sub["leptrino"] = dict(port=lt.get("port", "", str),
                           baudrate=lt.get("baudrate", 460800, int),
                           sync_on_external_input=lt.get("sync_on_external_input", False, bool))
    if kind == "leptrino" and not sub["leptrino"]["port"]:
        lt.fail("port", "", "the serial port of the sensor is needed (COM5, /dev/ttyACM0)")
    lt.done()
    a.done()
    acq = AcquisitionConfig(kind=kind, fs_Hz=fs, **sub)

    se = root.table_of("sensor")
    model = se.get("model", "PFS080YA501G6", str)
    direction = se.get("extension_direction", [1.0, 0.0, 0.0], list)
    if (not isinstance(direction, list) or len(direction) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in direction)
            or not any(direction)):
        se.fail("extension_direction", direction, "expected 3 numbers, not all zero (the "
                "extension axis in the sensor frame)")
    direction = tuple(float(x) for x in direction)
    cal = None
    if kind in ("caio", "nidaq"):
        channels = _axis_table(se, "channels", int, required=True)
        rated = _axis_table(se, "rated", float)
        out_V = _axis_table(se, "rated_output_V", float)
        offset = _axis_table(se, "offset_V", float)
        matrix = se.get("matrix", None, list)
        sync_ch = se.get("sync_channel", -1, int)
        try:
            cal = AnalogCalibration(
                channels=channels, rated=rated, rated_output_V=out_V, offset_V=offset,
                matrix=tuple(tuple(float(x) for x in row) for row in matrix)
                if matrix is not None else None,
                extension_direction=direction,
                sync_channel=None if sync_ch < 0 else sync_ch)
        except (ValueError, TypeError) as exc:
            raise HardwareConfigError(f"{source}: [sensor]: {exc}") from None
        if cal.sync_channel is None:
            raise HardwareConfigError(
                f"{source}: sensor.sync_channel is missing; wire the stimulator's sync "
                "output to an A/D channel and name it (it is recorded with every trial)")
    else:
        for key in ("channels", "rated", "rated_output_V", "offset_V", "matrix",
                    "sync_channel"):
            if key in se.table:
                se.fail(key, se.table[key], "only for analog chains (acquisition.kind caio "
                        "or nidaq); the Leptrino USB sensor reports its own rated values")
    se.done()

    e = root.table_of("estop")
    ekind = e.choice("kind", "none", {"none", "serial", "nidaq"})
    estop = EStopConfig(kind=ekind, port=e.get("port", "", str), line=e.get("line", "CTS", str),
                        released_level=e.get("released_level", True, bool))
    if ekind == "serial":
        if not estop.port:
            e.fail("port", "", "the USB-serial adapter's port is needed")
        if estop.line not in ("CTS", "DSR"):
            e.fail("line", estop.line, "valid: CTS, DSR")
    if ekind == "nidaq" and "/" not in estop.line:
        e.fail("line", estop.line, "a DAQmx digital line such as Dev1/port0/line0")
    e.done()
    root.done()
    return HardwareConfig(source=source, name=name, fake=fake, fake_speed=speed,
                          stimulator=stim, acquisition=acq, calibration=cal,
                          extension_direction=direction, sensor_model=model, estop=estop)


def _axis_table(reader: _Reader, key: str, kind, required: bool = False) -> dict:
    t = reader.table_of(key)
    if required and not t.table:
        reader.fail(key, {}, f"map the sensor's outputs to A/D channels, e.g. "
                    f"[sensor.{key}] Fx = 0")
    out = {}
    for axis in list(t.table):
        if axis not in AXES:
            t.fail(axis, t.table[axis], f"not a sensor axis; valid: {', '.join(AXES)}")
        out[axis] = t.get(axis, None, kind)
    t.done()
    return out
