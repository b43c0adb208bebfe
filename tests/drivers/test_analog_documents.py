"""The analog chain (Leptrino analog outputs on a Contec or NI A/D) against the vendors'
documents (issue 25, "Analog chain"): the sensor's 0 .. 3.3 V span, 1.5 V at no load and
1 V per rated load (Leptrino CFS manual No.M000104, 4.1); Contec's AioGetAiMaxChannels
("the current input method"); device names that are not ASCII.
"""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

import numpy as np
import pytest

from nmsid.drivers.analog_force import SENSOR_SPAN_V, AnalogCalibration, convert_block
from nmsid.drivers.caio import CaioAcquisition, declare, encode_device_name
from nmsid.drivers.errors import DeviceError, HardwareConfigError
from nmsid.drivers.fake_hardware import load_fake
from nmsid.drivers.hw_config import load_hw_config
from nmsid.protocols import os_platform

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "hw-config.example.toml"
CAL = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0}, rated_output_V={"Fx": 1.0},
                        offset_V={"Fx": 1.5}, sensor_span_V=SENSOR_SPAN_V)


@pytest.mark.parametrize("volts, flagged", [(1.5, False), (2.8, False), (0.3, False),
                                            (3.3, True), (3.29, True), (0.0, True)])
def test_over_range_at_the_edges_of_the_sensors_0_to_3_3_V_span(volts, flagged):
    # the old flag fired at |V| >= 9.95 V of the A/D range: never, for this sensor
    block = convert_block(np.array([[volts]] * 4), CAL, range_V=10.0)
    assert block.saturated is flagged


def test_the_example_hardware_file_follows_the_vendor_scaling(tmp_path):
    cfg = load_hw_config(EXAMPLE)
    cal = cfg.calibration
    assert set(cal.rated_output_V.values()) == {1.0} and set(cal.offset_V.values()) == {1.5}
    assert cal.sensor_span_V == (0.0, 3.3) and cal.implausible() == []
    # a 25 N push on Fx, as the sensor puts it out (manual 4.1): 1.5 V + 1 V x 25 / rated
    bench_mod = load_fake("bench")
    wiring = bench_mod.leptrino_analog_wiring(bench_mod.FakeBench(), {"Fx": 0}, cal.rated,
                                              noise_V=0.0)
    v = wiring[0](np.zeros(1), np.array([25.0]))
    volts = np.zeros((1, cal.n_channels))
    volts[:, list(cal.channels.values())] = 1.5
    volts[0, cal.channels["Fx"]] = v[0]
    assert cal.wrench(volts)[0, 0] == pytest.approx(25.0)


def test_a_rated_output_the_sensor_cannot_produce_is_warned_about(caplog):
    cal = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                            rated_output_V={"Fx": 10.0}, sensor_span_V=SENSOR_SPAN_V)
    assert "10 times too small" in cal.implausible()[0]
    lib = load_fake("fake_caio").FakeCaioLibrary(load_fake("bench").FakeBench(), wiring={})
    with caplog.at_level(logging.WARNING, logger="nmsid.drivers.caio"):
        CaioAcquisition(cal, lib=declare(lib))
    assert "rated_output_V.Fx = 10 V" in caplog.text


def _caio(cal, **kw):
    lib = load_fake("fake_caio").FakeCaioLibrary(load_fake("bench").FakeBench(), wiring={},
                                                 max_channels=16)
    return CaioAcquisition(cal, lib=declare(lib), **kw), lib


def test_max_channels_are_read_after_the_input_method():
    # Contec's help: AioGetAiMaxChannels gives the channels of the current input method;
    # differential input halves them (16 single-ended inputs = 8 differential channels)
    nine = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                             rated_output_V={"Fx": 1.0}, sync_channel=8)
    acq, lib = _caio(nine, input_method="differential")
    with pytest.raises(DeviceError, match="has 8 in differential input"):
        acq.open()
    seven = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                              rated_output_V={"Fx": 1.0}, sync_channel=6)
    acq, lib = _caio(seven, input_method="differential")
    acq.open()
    assert acq.max_channels == 8
    names = [c[0] for c in lib.calls]
    assert names.index("AioSetAiInputMethod") < names.index("AioGetAiMaxChannels")
    acq.close()


def test_a_device_name_that_is_not_ascii(monkeypatch):
    cal = AnalogCalibration(channels={"Fx": 0}, rated={"Fx": 500.0},
                            rated_output_V={"Fx": 1.0}, sync_channel=1)
    lib = load_fake("fake_caio").FakeCaioLibrary(load_fake("bench").FakeBench(), wiring={},
                                                 device_name="計測AIO")
    monkeypatch.setattr("locale.getpreferredencoding", lambda do_setlocale=True: "utf-8")
    with os_platform.forced("posix"):
        acq = CaioAcquisition(cal, lib=declare(lib), device_name="計測AIO")
        acq.open()   # was: UnicodeEncodeError (a traceback) before AioInit
        acq.close()
        monkeypatch.setattr("locale.getpreferredencoding",
                            lambda do_setlocale=True: "ascii")
        with pytest.raises(HardwareConfigError, match="rename the device"):
            encode_device_name("計測AIO")


def test_the_fake_caio_refuses_undocumented_trigger_codes():
    lib = declare(load_fake("fake_caio").FakeCaioLibrary(load_fake("bench").FakeBench(),
                                                         wiring={}))
    aio_id = ctypes.c_short(0)
    assert lib.AioInit(b"AIO000", ctypes.byref(aio_id)) == 0
    assert lib.AioSetAiStartTrigger(aio_id, ctypes.c_short(1)) == 0
    assert lib.AioSetAiStartTrigger(aio_id, ctypes.c_short(7)) != 0
    assert lib.AioSetAiStopTrigger(aio_id, ctypes.c_short(4)) == 0
    assert lib.AioSetAiStopTrigger(aio_id, ctypes.c_short(9)) != 0
