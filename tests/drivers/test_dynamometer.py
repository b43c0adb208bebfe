"""The analog dynamometer (a knee's or an ankle's torque, N m per V, on the rig's A/D):
hardware-file configuration, conversion, the automatic tare at rest (issue 37's, on the
torque output) and the interlock's torque limit acting on the tared torque (issue 41).
The fake torque output follows the vendor documents cited in testing/fakes/bench.py
(Noraxon's Biodex guide: -5 .. +5 V; Biodex addendum FN 14-379: a configured scale)."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.drivers.analog_force import NoLoadTare, convert_block
from nmsid.drivers.caio import CaioAcquisition, declare
from nmsid.drivers.dynamometer import DYNAMOMETER_SPAN_V, DynamometerCalibration
from nmsid.drivers.errors import HardwareConfigError
from nmsid.drivers.fake_hardware import analog_wiring, load_fake
from nmsid.drivers.hw_config import parse_hw_config
from tests.drivers.analog_trip import true_load_at_trip

NM_PER_V = 50.0
CAL = DynamometerCalibration(channel=0, Nm_per_V=NM_PER_V, offset_V=0.0, sync_channel=1)
REST_V = 0.3
"""The fake output rests 0.3 V off its nominal 0 V: 15 N m untared."""

HW = {"rig": {"fake": True},
      "acquisition": {"kind": "caio"},
      "sensor": {"kind": "dynamometer", "model": "Biodex System 4 Pro", "sync_channel": 1,
                 "dynamometer": {"channel": 0, "Nm_per_V": NM_PER_V, "offset_V": 0.0,
                                 "sign": -1}}}


def test_the_hardware_file_configures_a_dynamometer():
    cfg = parse_hw_config(HW, "rig.toml")
    cal = cfg.calibration
    assert isinstance(cal, DynamometerCalibration)
    assert (cal.channel, cal.Nm_per_V, cal.sign, cal.sync_channel) == (0, 50.0, -1.0, 1)
    assert cal.sensor_span_V == DYNAMOMETER_SPAN_V and cal.n_channels == 2
    assert "Biodex System 4 Pro" in cfg.describe()
    # sign -1: a dynamometer whose positive torque is the joint's negative direction
    volts = np.array([[0.2, 0.0]])
    assert cal.force_N(cal.wrench(volts))[0] == pytest.approx(-10.0)


@pytest.mark.parametrize("change, key", [
    ({"dynamometer": {"Nm_per_V": 50.0}}, "sensor.dynamometer.channel"),
    ({"dynamometer": {"channel": 0}}, "sensor.dynamometer.Nm_per_V"),
    ({"dynamometer": {"channel": 1, "Nm_per_V": 50.0}}, "sensor.sync_channel"),
    ({"dynamometer": {"channel": 0, "Nm_per_V": 50.0}, "channels": {"Fx": 3}},
     "sensor.channels"),
    ({"dynamometer": {"channel": 0, "Nm_per_V": 50.0, "sign": 2}}, "sensor.dynamometer.sign"),
])
def test_a_bad_dynamometer_table_is_one_line_naming_the_setting(change, key):
    sensor = {"kind": "dynamometer", "sync_channel": 1, **change}
    with pytest.raises(HardwareConfigError) as e:
        parse_hw_config({**HW, "sensor": sensor}, "rig.toml")
    assert key in str(e.value) and "\n" not in str(e.value)


def test_a_dynamometer_needs_an_analog_chain():
    with pytest.raises(HardwareConfigError, match="sensor.kind.*analog chain"):
        parse_hw_config({**HW, "acquisition": {"kind": "leptrino", "fs_Hz": 1000.0,
                                               "leptrino": {"port": "COM5"}}},
                        "rig.toml")


@pytest.mark.parametrize("volts, flagged", [(0.0, False), (4.9, False), (-4.9, False),
                                            (5.0, True), (-4.99, True)])
def test_over_range_at_the_edges_of_the_outputs_span(volts, flagged):
    block = convert_block(np.array([[volts, 0.0]] * 4), CAL, range_V=10.0)
    assert block.saturated is flagged
    assert block.force_N[0] == pytest.approx(volts * NM_PER_V)
    assert block.wrench is None              # one torque, never a six-axis wrench


def test_implausible_scales_are_warned_about():
    assert DynamometerCalibration(0, 50.0).implausible() == []
    assert "V per N m" in DynamometerCalibration(0, 0.02).implausible()[0]


def _dynamometer_rig(fake_mcs, torque_fn):
    """The fake Contec with the fake torque output resting at REST_V; ``torque_fn(t)`` is
    the joint torque (N m) at bench time t."""
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=4.0)   # 4x wall; with the deep FIFO (conftest), a
    # loaded host (2 cores, load ~6) cannot overrun it: at 20x it did, once, in the tare
    inner = bench_mod.dynamometer_analog_wiring(bench, 0, NM_PER_V, rest_V=REST_V)
    wiring = {0: lambda t, f: inner[0](t, torque_fn(t))}
    lib = load_fake("fake_caio").FakeCaioLibrary(bench, wiring=wiring)
    cal = DynamometerCalibration(channel=0, Nm_per_V=NM_PER_V, offset_V=0.0)
    return bench, lib, CaioAcquisition(cal, lib=declare(lib))


def _read(acq, n):
    out = []
    while sum(len(c.force_N) for c in out) < n:
        c = acq.read(1.0)
        assert c is not None, "no samples"
        out.append(c)
    return np.concatenate([c.force_N for c in out])[:n]


def test_a_dynamometer_resting_off_nominal_reads_zero_after_the_automatic_tare(
        fake_mcs, deep_fake_fifo):
    bench, _lib, acq = _dynamometer_rig(fake_mcs, lambda t: np.zeros_like(t))
    try:
        acq.configure(2000.0)
        acq.start(400, triggered=False)
        torque = _read(acq, 400)
        # untared, 0.3 V x 50 N m/V = 15 N m at rest; tared, within 0.5 N m of zero
        assert np.abs(torque).max() < 0.5
        assert acq._tare.no_load_V["Mz"] == pytest.approx(REST_V, abs=1e-3)
    finally:
        acq.close()


def test_the_torque_limit_trips_at_its_configured_torque_on_the_tared_torque(
        fake_mcs, deep_fake_fifo):
    # the torque rises 10 N m/s; untared it would trip at rest (15 N m > 10 N m); tared,
    # at the limit within 0.5 N m
    true_Nm = true_load_at_trip(lambda load: _dynamometer_rig(fake_mcs, load), 10.0, 10.0)
    assert abs(true_Nm - 10.0) < 0.5, true_Nm


def test_the_tare_measures_the_torque_outputs_rest():
    tare = NoLoadTare(clock=lambda: 0.0)
    tare.update(np.column_stack([np.full(10, REST_V), np.zeros(10)]), CAL, "test")
    assert tare.wrench[5] == pytest.approx(REST_V * NM_PER_V)
    block = convert_block(np.array([[REST_V + 0.1, 0.0]]), CAL, 10.0, tare_wrench=tare.wrench)
    assert block.force_N[0] == pytest.approx(0.1 * NM_PER_V)


def test_fake_mode_wires_the_torque_output_and_the_sync():
    cfg = parse_hw_config(HW, "rig.toml")
    bench = load_fake("bench").FakeBench()
    wiring = analog_wiring(cfg, bench)
    assert set(wiring) == {0, 1}
    # sign -1 in the file: +10 N m of joint torque puts out rest - 0.2 V
    v = wiring[0](np.zeros(1), np.array([10.0]))
    assert v[0] == pytest.approx(load_fake("bench").DYNAMOMETER_REST_V - 0.2, abs=0.005)


def test_the_example_files_dynamometer_block_loads(tmp_path):
    from pathlib import Path
    text = (Path(__file__).resolve().parents[2] / "docs" / "hw-config.example.toml").read_text(
        encoding="utf-8")
    head, tail = text.split("# --- A knee or an ankle", 1)
    tail = tail[tail.index("# [sensor]"):]
    block = "\n".join(line[2:] for line in tail.splitlines()
                      if line.startswith("# ") and ("=" in line or line.startswith("# [")))
    six_axis = head.index("[sensor]")
    estop = head.index("[estop]")
    f = tmp_path / "knee-rig.toml"
    f.write_text(head[:six_axis] + block + "\n\n" + head[estop:], encoding="utf-8")
    from nmsid.drivers.hw_config import load_hw_config
    cfg = load_hw_config(f)
    assert isinstance(cfg.calibration, DynamometerCalibration)
    assert cfg.calibration.Nm_per_V == 50.0 and cfg.calibration.sync_channel == 6
