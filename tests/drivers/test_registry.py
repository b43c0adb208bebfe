"""The device registry: the one table of stimulator kinds (each entry's settings model is its
kind's), no import cycle with the hardware file's reader, and no code outside the registry
and a kind's own modules names a kind."""

from __future__ import annotations

import ast
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from nmsid.drivers import registry
from nmsid.drivers.caio import CaioAcquisition
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.estop_switch import NidaqEStop
from nmsid.drivers.hardware import make_acquisition, make_estop, make_stimulator, prepare
from nmsid.drivers.hw_config import AcquisitionSettings, EStopConfig, parse_hw_config
from nmsid.drivers.interfaces import Stimulator
from nmsid.drivers.leptrino import LeptrinoAcquisition
from nmsid.drivers.nidaq import NidaqAcquisition
from nmsid.drivers.rehastim2 import Rehastim2Stimulator
from nmsid.drivers.rehastim2_settings import Rehastim2Config
from nmsid.drivers.stg4002_settings import Stg4002Config

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("analysis", "cli", "drivers", "export", "nmsid", "protocols", "rig",
            "sim_backends", "study", "testing")
#: where a kind may be named: the registry and each kind's own modules
ALLOWED = {"drivers/registry.py"}
OWN_PREFIXES = {"stg4002": ("drivers/stg", "drivers/mcs_usb", "testing/fakes/fake_mcs_usb",
                            "testing/fakes/fake_stg"),
                "rehastim2": ("drivers/rehastim2", "testing/fakes/fake_rehastim2"),
                "p24": ("drivers/p24",), "rehamove3": ("drivers/rehamove3",)}
#: an acquisition kind's own modules (driver, vendor surface, fake); the E-stop on a DAQmx
#: line is the nidaq driver's too
ACQ_OWN_PREFIXES = {"caio": ("drivers/caio", "testing/fakes/fake_caio"),
                    "nidaq": ("drivers/nidaq", "testing/fakes/fake_nidaqmx"),
                    "leptrino": ("drivers/leptrino", "testing/fakes/leptrino")}


def test_each_entry_is_its_kinds_and_validates_its_table():
    assert registry.DEFAULT_STIMULATOR in registry.STIMULATORS
    for kind, entry in registry.STIMULATORS.items():
        assert entry.kind == kind and entry.title
        assert entry.settings.__pydantic_fields__["kind"].default == kind  # its own model
        assert entry.settings.__module__ == f"nmsid.drivers.{kind}_settings"


def test_the_registry_never_imports_the_hardware_file_reader():
    # hw_config validates through the registry; the registry names hw_config's types only
    # for the type checker, so either may be imported first
    tree = ast.parse((ROOT / "drivers" / "registry.py").read_text(encoding="utf-8"))
    runtime = [node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
    assert not [n for n in runtime if "hw_config" in ast.unparse(n)]
    for first, second in (("registry", "hw_config"), ("hw_config", "registry")):
        subprocess.run([sys.executable, "-c", f"import nmsid.drivers.{first}, "
                        f"nmsid.drivers.{second}"], check=True, timeout=120)


def test_no_kind_named_outside_the_registry():
    offenders = []
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            if rel in ALLOWED:
                continue
            text = path.read_text(encoding="utf-8")
            if not any(kind in text for kind in registry.STIMULATORS):
                continue            # no kind named at all: nothing to parse
            tree = ast.parse(text)
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and node.value in registry.STIMULATORS:
                    if not rel.startswith(OWN_PREFIXES[node.value]):
                        offenders.append(f"{rel}:{node.lineno}: {node.value!r}")
    assert offenders == []


def _acquisition_names(path: Path) -> list[tuple[int, str, bool]]:
    """``(line, kind, inside a function)`` for each acquisition kind named in ``path``."""
    text = path.read_text(encoding="utf-8")
    if not any(kind in text for kind in registry.ACQUISITIONS):
        return []
    found = []

    def walk(node, in_function):
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                      ast.Lambda))
            if isinstance(child, ast.Constant) and child.value in registry.ACQUISITIONS:
                found.append((child.lineno, child.value, inner))
            walk(child, inner)
    walk(ast.parse(text), False)
    return found


def test_acquisition_settings_and_registry_agree():
    kinds = typing.get_args(AcquisitionSettings.__pydantic_fields__["kind"].annotation)
    assert set(kinds) == set(registry.ACQUISITIONS)
    estops = typing.get_args(EStopConfig.__pydantic_fields__["kind"].annotation)
    assert set(estops) == set(registry.ESTOPS)
    for kind, entry in registry.ACQUISITIONS.items():
        assert entry.kind == kind
    for kind, entry in registry.ESTOPS.items():
        assert entry.kind == kind


def test_no_acquisition_kind_named_outside_the_registry():
    """Nothing outside the registry and each kind's own modules names an acquisition kind;
    the settings file may, only in its declarations (the Literal, a default), never in a
    function (a validator comparing the kind)."""
    offenders = []
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            if rel == "drivers/registry.py":
                continue
            for line, kind, in_function in _acquisition_names(path):
                if rel == "drivers/hw_config.py" and not in_function:
                    continue
                if not rel.startswith(ACQ_OWN_PREFIXES[kind]):
                    offenders.append(f"{rel}:{line}: {kind!r}")
    assert offenders == []


def test_the_kind_scan_sees_a_comparison(tmp_path):
    """The scan above finds a kind compared in a function (and only there, for hw_config)."""
    probe = tmp_path / "probe.py"
    probe.write_text('KIND = "caio"\n\n\ndef f(a):\n    return a.kind == "leptrino"\n',
                     encoding="utf-8")
    assert _acquisition_names(probe) == [(1, "caio", False), (5, "leptrino", True)]


ANALOG_SENSOR = {"channels": {"Fx": 0}, "rated": {"Fx": 500.0},
                 "rated_output_V": {"Fx": 10.0}, "sync_channel": 1}


def _acq_file(kind: str) -> dict:
    if registry.ACQUISITIONS[kind].analog:
        return {"acquisition": {"kind": kind}, "sensor": ANALOG_SENSOR}
    return {"acquisition": {"kind": kind, "fs_Hz": 1200.0, kind: {"port": "COM5"}}}


DRIVERS = {"caio": CaioAcquisition, "nidaq": NidaqAcquisition, "leptrino": LeptrinoAcquisition}


@pytest.mark.parametrize("kind", sorted(registry.ACQUISITIONS))
def test_every_acquisition_kind_is_built_from_its_entry(kind):
    """Title, calibration (analog chains only) and driver all come from the kind's entry."""
    entry = registry.ACQUISITIONS[kind]
    cfg = parse_hw_config(_acq_file(kind), "rig.toml")
    assert registry.acquisition_kind(cfg) is entry
    assert f"+ {entry.title} (" in cfg.describe()
    assert (cfg.calibration is not None) == entry.analog
    acq = make_acquisition(cfg, None)
    try:
        assert isinstance(acq, DRIVERS[kind])
    finally:
        acq.close()


@pytest.mark.parametrize("kind", sorted(k for k, e in registry.ACQUISITIONS.items()
                                        if not e.analog))
def test_a_chain_without_analog_inputs_refuses_the_monitor_naming_the_analog_kinds(kind):
    data = _acq_file(kind)
    data["acquisition"]["monitor_channel"] = 7
    with pytest.raises(HardwareConfigError) as e:
        parse_hw_config(data, "rig.toml")
    msg = str(e.value)
    assert msg.startswith("rig.toml: acquisition.monitor_channel = 7")
    for analog in (k for k, en in registry.ACQUISITIONS.items() if en.analog):
        assert analog in msg


def test_unknown_acquisition_kind_in_the_registry_is_one_line():
    with pytest.raises(HardwareConfigError, match="valid caio, nidaq, leptrino"):
        registry.acquisition_entry("labjack")


def test_fake_nidaq_estop_beside_a_caio_chain_gets_its_line():
    """The E-stop entry installs the fake DAQmx when the acquisition entry did not."""
    data = {**_acq_file("caio"), "rig": {"fake": True},
            "estop": {"kind": "nidaq", "line": "Dev1/port0/line0"}}
    cfg, stack, clock = prepare(parse_hw_config(data, "x"))
    try:
        estop = make_estop(cfg, stack)
        try:
            assert isinstance(estop, NidaqEStop) and estop.is_pressed() is False
        finally:
            estop.close()
    finally:
        stack.close()


def test_kind_defaults_to_the_stg4002_and_rehastim2_is_typed():
    base = {"acquisition": {"kind": "leptrino", "fs_Hz": 1200.0,
                            "leptrino": {"port": "COM5"}}}
    assert isinstance(parse_hw_config(base, "x").stimulator, Stg4002Config)
    cfg = parse_hw_config({**base, "stimulator": {"kind": "rehastim2", "port": "COM4"}}, "x")
    assert isinstance(cfg.stimulator, Rehastim2Config)
    assert cfg.stimulator.pulse_rate_Hz == 40.0 and cfg.stimulator.pulse_width_us == 300
    assert "Hasomed RehaStim2" in cfg.describe()
    stim = make_stimulator(cfg, None, None)
    assert isinstance(stim, Rehastim2Stimulator) and isinstance(stim, Stimulator)


@pytest.mark.parametrize("table, key", [
    ({"kind": "rehastim9"}, "stimulator.kind"),
    ({"kind": "rehastim2"}, "stimulator.port"),
    ({"kind": "rehastim2", "port": "COM4", "pulse_rate_Hz": 33.0}, "stimulator.pulse_rate_Hz"),
    ({"kind": "rehastim2", "port": "COM4", "ceiling_ext_mA": 131.0}, "stimulator.ceiling_ext_mA"),
    ({"kind": "rehastim2", "port": "COM4", "sync_out": 1}, "stimulator.sync_out"),
    ({"kind": "stg4002", "pulse_width_us": 300}, "stimulator.pulse_width_us"),
])
def test_bad_stimulator_tables_are_one_line_naming_the_key(table, key):
    base = {"acquisition": {"kind": "leptrino", "fs_Hz": 1200.0,
                            "leptrino": {"port": "COM5"}}}
    with pytest.raises(HardwareConfigError) as e:
        parse_hw_config({**base, "stimulator": table}, "rig.toml")
    msg = str(e.value)
    assert msg.startswith(f"rig.toml: {key} = ") and "\n" not in msg


def test_fake_mode_installs_the_configured_kinds_fake():
    base = {"rig": {"fake": True},
            "acquisition": {"kind": "leptrino", "fs_Hz": 1200.0, "leptrino": {"port": "COM5"}},
            "stimulator": {"kind": "rehastim2", "port": "COM4"}}
    cfg, stack, clock = prepare(parse_hw_config(base, "x"))
    try:
        fake = stack.stimulator_fake
        assert stack.bench.stimulator is fake
        stim = make_stimulator(cfg, stack, clock)
        stim.connect()
        assert fake.connected
        stim.disconnect()
    finally:
        stack.close()


@pytest.mark.parametrize("kind", sorted(registry.STIMULATORS))
def test_every_kind_reports_what_a_checked_trial_would_deliver(kind):
    """Each entry's charge report runs on its own settings (the STG's was never called)."""
    import numpy as np  # noqa: PLC0415

    from nmsid.drivers.interfaces import CheckedWaveform  # noqa: PLC0415
    entry = registry.STIMULATORS[kind]
    import dataclasses  # noqa: PLC0415
    names = {f.name for f in dataclasses.fields(entry.settings)}
    extra = {"port": "COM5"} if "port" in names else {}
    settings = entry.settings(ceiling_ext_mA=10.0, ceiling_flex_mA=10.0, **extra)
    env = np.linspace(0.0, 8.0, 2000)
    report = entry.report(settings, CheckedWaveform(env, env[::-1].copy(), 2000.0, 1000.0,
                                                    10.0, 10.0))
    assert set(report["channels"]) >= {"extensor", "flexor"}
