"""Shared fixtures of the driver tests: the fakes, the package ``testing.fakes``."""

from __future__ import annotations

import pytest

from nmsid.drivers.fake_hardware import load_fake


def pytest_configure(config):
    config.addinivalue_line("markers", "full_rate_measurement: keep the Leptrino driver's "
                            "1 s record-rate measurement (tests that check the figure)")


@pytest.fixture(autouse=True)
def _short_rate_measurement(request, monkeypatch):
    """The Leptrino record rate is measured for 1 s at connect; 0.3 s is enough for tests
    that do not check the figure (keeps the suite fast). Tests marked
    ``full_rate_measurement`` keep the driver's 1 s."""
    if request.node.get_closest_marker("full_rate_measurement") is None:
        monkeypatch.setattr("nmsid.drivers.leptrino.RATE_MEASURE_S", 0.3)


@pytest.fixture
def leptrino_emulator():
    mod = load_fake("leptrino_emulator")
    emulators = []

    def make(**kwargs):
        emu = mod.LeptrinoEmulator(**kwargs)
        emu.__enter__()
        emulators.append(emu)
        return emu

    yield make
    for emu in emulators:
        emu.close()  # also after unplug(): removes the stable port path


@pytest.fixture
def fake_mcs(monkeypatch):
    """Fake pythonnet + McsUsbNet in ``sys.modules`` (undone after the test)."""
    import sys

    mod = load_fake("fake_mcs_usb")
    bench = load_fake("bench").FakeBench(speed=1.0)
    mods: dict = {}

    def setup(hardware=None, bench=bench):
        mods.clear()
        mod.install(bench=bench, hardware=hardware, modules=mods)
        for name, m in mods.items():
            monkeypatch.setitem(sys.modules, name, m)
        return mod.registry()

    setup.module = mod
    setup.bench = bench
    setup()
    return setup


@pytest.fixture
def fake_nidaqmx(monkeypatch):
    """Fake nidaqmx in ``sys.modules``; call with (bench, wiring, di_lines)."""
    import sys

    mod = load_fake("fake_nidaqmx")

    def setup(bench=None, **kw):
        mods: dict = {}
        mod.install(bench=bench, modules=mods, **kw)
        for name, m in mods.items():
            monkeypatch.setitem(sys.modules, name, m)
        return mod.state()

    setup.module = mod
    yield setup
    for task in mod.state().tasks:
        task.close()


_VENDOR_MODULES = ("clr", "System", "Mcs", "Mcs.Usb", "nidaqmx", "nidaqmx.constants",
                   "nidaqmx.errors", "nidaqmx.stream_readers", "nidaqmx.system")


@pytest.fixture(autouse=True)
def _restore_vendor_modules():
    """Fake mode installs fake vendor modules process-wide: undo it after each test."""
    import sys

    saved = {name: sys.modules.get(name) for name in _VENDOR_MODULES}
    yield
    for name, mod in saved.items():
        if mod is None:
            sys.modules.pop(name, None)
        else:
            sys.modules[name] = mod


@pytest.fixture
def write_hw_config():
    """Factory writing a fake-mode hardware config (end-to-end and probe tests)."""
    return _write_hw_config


def _write_hw_config(path, *, kind="caio", speed=10.0, fake=True, estop="serial",
                    fs_Hz=2000.0, monitor=None, extra=()):
    """A fake-mode hardware config for the end-to-end and probe tests (``monitor``: the
    dry run's resistor input; ``extra``: more lines of ``[acquisition]``)."""
    lines = ["[rig]", f"fake = {'true' if fake else 'false'}", f"fake_speed = {speed}",
             "[stimulator]", "ceiling_ext_mA = 16.0", "ceiling_flex_mA = 16.0",
             "[acquisition]", f'kind = "{kind}"', f"fs_Hz = {fs_Hz}",
             *([f"monitor_channel = {monitor}"] if monitor is not None else []), *extra]
    if kind == "leptrino":
        lines += ["[acquisition.leptrino]", 'port = "COM5"']
    else:
        lines += ["[sensor]", "sync_channel = 6", "[sensor.channels]",
                  *[f"{a} = {i}" for i, a in enumerate(("Fx", "Fy", "Fz", "Mx", "My", "Mz"))],
                  "[sensor.rated]", "Fx = 500.0", "Fy = 500.0", "Fz = 1000.0", "Mx = 10.0",
                  "My = 10.0", "Mz = 10.0", "[sensor.rated_output_V]",   # manual 4.1
                  *[f"{a} = 1.0" for a in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")],
                  "[sensor.offset_V]",
                  *[f"{a} = 1.5" for a in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")]]
    if estop == "serial":
        lines += ["[estop]", 'kind = "serial"', 'port = "COM7"', 'line = "CTS"']
    elif estop == "nidaq":
        lines += ["[estop]", 'kind = "nidaq"', 'line = "Dev1/port0/line0"']
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def child_modules(tmp_path, monkeypatch):
    """``nmsid probe`` checks real devices in child processes (one per device), which an
    in-process ``monkeypatch`` of ``sys.modules`` does not reach: ``add(name, source)``
    puts a module on the children's PYTHONPATH instead (``sitecustomize`` runs in each
    child at start-up)."""
    import os
    lib = tmp_path / "child_modules"
    lib.mkdir()
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(lib), *filter(None, [os.environ.get("PYTHONPATH")])]))

    def add(name: str, source: str) -> None:
        (lib / f"{name}.py").write_text(source, encoding="utf-8")
    return add


FAKE_MCS_IN_CHILD = ("import sys\n"
                     "from nmsid.drivers.fake_hardware import load_fake\n"
                     "load_fake('fake_mcs_usb').install(modules=sys.modules)\n")
"""A child's ``sitecustomize``: the fake pythonnet + McsUsbNet, as ``fake_mcs`` in-process."""


@pytest.fixture
def deep_fake_fifo(monkeypatch):
    """A deep fake CAIO FIFO (dry run, dynamometer). It holds 4096 scans: 0.4 s at the dry run's
    10 kHz. A loaded test host (2 cores, several suites) can keep this process off the
    CPU for longer, and the record would then fail as overrun; the FIFO's depth is not
    what these tests check (``tests/drivers/test_caio.py`` checks the overrun flag), so
    it holds 6.5 s here."""
    from nmsid.testing.fakes import fake_caio
    real = fake_caio.FakeCaioLibrary.__init__

    def init(self, bench, **kw):
        kw["fifo_samples"] = max(kw.get("fifo_samples", 0), 1 << 16)
        real(self, bench, **kw)
    monkeypatch.setattr(fake_caio.FakeCaioLibrary, "__init__", init)
