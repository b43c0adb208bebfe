"""Shared fixtures of the driver tests: the fakes, loaded as ``nmsid_hw_fakes``."""

from __future__ import annotations

import pytest

from drivers.fake_hardware import load_fake


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
        if emu.master != -1:
            emu.close()


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
