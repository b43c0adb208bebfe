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
