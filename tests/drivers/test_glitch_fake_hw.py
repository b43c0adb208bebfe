"""A USB glitch between trials on the fake hardware stack, each acquisition in turn: the
driver is found dead before the next trial, reconnects (a new port handle / device id /
DAQmx task), the operator confirms, and the session completes in the same process."""

from __future__ import annotations

import pytest

from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.hardware import make_hw_rig
from nmsid.protocols.config import config_from_dict
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy


def _glitch(kind, devices):
    inner = devices.acquisition._inner
    if kind == "leptrino":
        emu = devices.acquisition._stack.emulator
        emu.unplug()
        emu.replug()
    elif kind == "caio":
        inner._lib.unplug()
        inner._lib.replug()
    else:
        mod = load_fake("fake_nidaqmx")
        mod.unplug()
        mod.replug()


@pytest.mark.parametrize("kind", ["leptrino", "caio", "nidaq"])
def test_usb_glitch_between_trials_on_fake_hardware(tmp_path, write_hw_config, kind):
    fs = 1200.0 if kind == "leptrino" else 2000.0
    devices = make_hw_rig(write_hw_config(tmp_path / "hw.toml", kind=kind, speed=4.0,
                                          fs_Hz=fs, estop="none"))

    class GlitchAfterFirstTrial(EngineObserver):
        def on_trial_finished(self, index, trial):
            if index == 0:
                _glitch(kind, devices)

    cfg = config_from_dict({
        "participant": "HW03", "seed": 1, "interlock": {"stall_timeout_s": 2.0},
        "protocol": {"sE_levels": [0.5, 0.9], "repeats": 1, "steady_s": 0.3, "chirp_s": 0.5,
                     "rest_s": 0.0, "fs_Hz": fs},
        "calibration": {"manual": {"Iemin_mA": 2.5, "Iemax_mA": 7.0, "Ifmin_mA": 2.5,
                                   "Ifmax_mA": 7.0}}})
    path = tmp_path / "s.h5"
    asked = []
    try:
        s = Engine(cfg, devices, path, observer=GlitchAfterFirstTrial(),
                   trip_policy=TripPolicy.END_SESSION,
                   on_device_glitch=lambda what, ok: asked.append(ok) or True).run()
    finally:
        devices.close()
    assert s.ended_by == "schedule complete", s.ended_by
    assert s.n_completed == 2 and s.n_aborted == 0
    assert asked == [True]
    sess = read_session(path)
    assert validate_session(path) == []
    ev = [(e.kind, e.detail) for e in sess.events]
    assert [d for k, d in ev if k == "device_glitch"][0].startswith("acquisition: ")
    assert [d for k, d in ev if k == "reconnect_attempt"] == [
        "acquisition: attempt 1 of 3 succeeded"]
    assert [t.n_samples for t in sess.trials] == [int(0.8 * fs)] * 2
