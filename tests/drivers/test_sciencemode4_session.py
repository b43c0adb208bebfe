"""Whole sessions on a (fake) Hasomed P24 and RehaMove3 through the one engine: calibration,
the schedule, a lost packet, an E-stop press; then ``nmsid run`` and ``identify``.

The fake (``testing/fakes/fake_sciencemode4.py``) speaks ScienceMode4 at the byte level; the
fake bench's force follows the pulses it executed.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.cli import main
from nmsid.drivers import sciencemode4_protocol as sm4
from nmsid.drivers.hardware import make_hw_rig
from nmsid.protocols.config import config_from_dict
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy

RELAXED_INTERLOCK = {"stall_timeout_s": 2.0}
KINDS = {"p24": ("Hasomed P24", 5), "rehamove3": ("Hasomed RehaMove3", 3)}


def write_sm4_config(path, kind, *, speed=4.0, extra=()):
    flexor = KINDS[kind][1]
    lines = ["[rig]", "fake = true", f"fake_speed = {speed}",
             "[stimulator]", f'kind = "{kind}"', 'port = "COM5"', "extensor_channel = 1",
             f"flexor_channel = {flexor}", "ceiling_ext_mA = 16.0", "ceiling_flex_mA = 16.0",
             *extra, "[acquisition]", 'kind = "caio"', "fs_Hz = 2000.0",
             "[sensor]", "sync_channel = 6", "[sensor.channels]", "Fx = 0",
             "[sensor.rated]", "Fx = 500.0", "[sensor.rated_output_V]", "Fx = 1.0",
             "[sensor.offset_V]", "Fx = 1.5",
             "[estop]", 'kind = "serial"', 'port = "COM7"', 'line = "CTS"']
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("kind", list(KINDS))
def test_session_with_a_lost_packet_and_an_estop_press(tmp_path, kind):
    devices = make_hw_rig(write_sm4_config(tmp_path / "sm4.toml", kind))
    assert KINDS[kind][0] in devices.backend
    fake = devices.acquisition._stack.stimulator_fake
    path = tmp_path / "s.h5"
    pressed: dict = {}

    class Faults(EngineObserver):
        def on_trial_finished(self, index, trial):
            if index == 0:                     # lost on the line: the trial goes on
                fake.lose_next(sm4.LL_CHANNEL_CONFIG, 3)

        def on_chunk(self, index, start_index, force_N, *rest):
            if index == 2 and start_index + len(force_N) >= 1200 and not pressed:
                pressed["t"] = fake.clock()
                devices.estop._ser.rts = False   # the NC switch opens the loop

    cfg = config_from_dict({
        "participant": "SM01", "seed": 3, "interlock": RELAXED_INTERLOCK,
        "protocol": {"sE_levels": [0.5, 0.9, 0.7], "repeats": 1, "steady_s": 0.4,
                     "chirp_s": 0.8, "rest_s": 0.0},
        "calibration": {"hold_s": 0.2, "baseline_s": 0.1, "ceiling_ext_mA": 15.0,
                        "ceiling_flex_mA": 15.0}})
    try:
        summary = Engine(cfg, devices, path, observer=Faults(),
                         trip_policy=TripPolicy.END_SESSION).run()
    finally:
        devices.close()
    assert summary.n_completed == 2, summary
    assert validate_session(path) == []
    s = read_session(path)
    assert 1.0 <= s.calibration.Iemin_mA <= s.calibration.Iemax_mA <= 15.0
    assert len(fake.lost) >= 3 and set(fake.lost) == {sm4.LL_CHANNEL_CONFIG}
    done = [t for t in s.trials if t.status == "completed"]
    unanswered = 0
    for t in done:
        stim = t.extra_attrs["stimulation_json"]
        stim = json.loads(stim) if isinstance(stim, str) else stim
        assert stim["device"] == KINDS[kind][0]
        amps = np.asarray(stim["channels"]["extensor"]["pulse_current_mA"])
        assert amps.size, json.dumps({k: v for k, v in stim.items() if k != "channels"})
        assert amps.max() <= 15.0 and np.all(amps * 2 == np.round(amps * 2))
        unanswered += stim["updates_unanswered"]
    assert unanswered >= 2     # counted, not hidden, not a fault: 3 commands lost, one per
    #                            channel and pulse, so at least 2 updates
    aborted = [t for t in s.trials if t.status == "aborted"]
    assert aborted and "estop" in aborted[0].abort_reason.lower()
    # E-stop to last pulse, on the fake's clock: at most one pulse period (40 Hz)
    last = max(p[0] for p in fake.pulses)
    assert last - pressed["t"] <= 1 / 40.0 + 0.05, last - pressed["t"]
    assert fake.level == sm4.STIM_NONE and fake.stops[-1] >= pressed["t"]
    assert max(p[2] for p in fake.pulses) <= 15.0


def test_mid_level_session_with_a_lost_update_and_an_estop(tmp_path):
    devices = make_hw_rig(write_sm4_config(tmp_path / "mid.toml", "rehamove3",
                                           extra=('mode = "mid"',)))
    fake = devices.acquisition._stack.stimulator_fake
    pressed: dict = {}

    class Faults(EngineObserver):
        def on_trial_finished(self, index, trial):
            if index == 0:
                fake.lose_next(sm4.ML_UPDATE, 2)

        def on_chunk(self, index, start_index, force_N, *rest):
            if index == 1 and start_index + len(force_N) >= 1200 and not pressed:
                pressed["t"] = fake.clock()
                devices.estop._ser.rts = False

    cfg = config_from_dict({
        "participant": "SM03", "seed": 4, "interlock": RELAXED_INTERLOCK,
        "protocol": {"sE_levels": [0.5, 0.9], "repeats": 1, "steady_s": 0.4,
                     "chirp_s": 0.8, "rest_s": 0.0},
        "calibration": {"manual": {"Iemin_mA": 2.5, "Iemax_mA": 7.0, "Ifmin_mA": 2.5,
                                   "Ifmax_mA": 7.0}}})
    path = tmp_path / "s.h5"
    try:
        summary = Engine(cfg, devices, path, observer=Faults(),
                         trip_policy=TripPolicy.END_SESSION).run()
    finally:
        devices.close()
    assert summary.n_completed == 1 and validate_session(path) == []
    assert fake.lost == [sm4.ML_UPDATE] * 2
    aborted = [t for t in read_session(path).trials if t.status == "aborted"]
    assert aborted and "estop" in aborted[0].abort_reason.lower()
    # the device's own pulses end with the confirmed Ml_stop, within one period (25 ms)
    assert fake.ml_spans[-1][1] - pressed["t"] <= 1 / 40.0 + 0.05
    assert fake.level == sm4.STIM_NONE and fake.keepalive_expiries == 0
    assert all(c <= 7.0 for _, _, chans in fake.ml_spans for _, c in chans.values())


@pytest.mark.parametrize("kind", list(KINDS))
def test_nmsid_run_then_identify(tmp_path, capsys, kind):
    hw = write_sm4_config(tmp_path / "sm4.toml", kind, speed=5.0)
    proto = tmp_path / "p.toml"
    proto.write_text('participant = "SM02"\nseed = 5\n[protocol]\nsE_levels = [0.7]\n'
                     'repeats = 2\nsteady_s = 0.5\nchirp_s = 2.0\nrest_s = 0.0\n'
                     '[calibration]\nhold_s = 0.2\nbaseline_s = 0.1\n'
                     '[interlock]\nstall_timeout_s = 2.0\n', encoding="utf-8")
    out = tmp_path / "run.h5"
    rc = main(["run", "--backend", "hw", "--hw-config", str(hw), "--config", str(proto),
               "--out", str(out), "--no-identify", "--quiet"])
    assert rc == 0, capsys.readouterr()
    assert validate_session(out) == []
    assert KINDS[kind][0] in read_session(out).backend
    rc = main(["identify", str(out), "--out", str(tmp_path / "id")])
    assert rc == 0, capsys.readouterr()


def test_a_hardware_file_outside_the_rehamove3_range_is_one_line(tmp_path, capsys):
    hw = write_sm4_config(tmp_path / "rm3.toml", "rehamove3")
    hw.write_text(hw.read_text(encoding="utf-8").replace("flexor_channel = 3",
                                                         "flexor_channel = 6"),
                  encoding="utf-8")
    rc = main(["probe", "--hw-config", str(hw)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "stimulator.flexor_channel" in err[0], err


def test_nmsid_stimulation_and_probe_on_a_p24(tmp_path, capsys):
    hw = write_sm4_config(tmp_path / "p24.toml", "p24")
    out = tmp_path / "stim"
    assert main(["stimulation", "--hw-config", str(hw), "--calibration", "2,10,2,10",
                 "--out", str(out)]) == 0
    assert "as Hasomed P24 delivers them (biphasic_pulses)" in capsys.readouterr().out
    report = json.loads((out / "stimulation.json").read_text(encoding="utf-8"))
    for lv in report["levels"]:
        for ch in lv["channels"].values():
            assert ch["peak_current_mA"] <= 10.0 and ch["pulses"] == 600   # 15 s at 40 Hz
            assert ch["max_charge_per_phase_nC"] == ch["peak_current_mA"] * 300
    assert main(["probe", "--hw-config", str(hw)]) == 0
    assert "Hasomed P24 (ScienceMode4, low level)" in capsys.readouterr().out
