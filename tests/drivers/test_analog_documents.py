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
from tests.drivers.analog_trip import true_load_at_trip

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
                                              noise_V=0.0, rest_V={"Fx": 1.5})
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


# -- the automatic tare (issue 37 item 5; CFS manual 4.2) ----------------------------------
def _resting_rig(fake_mcs, force_fn):
    """A 500 N Fx axis resting at 1.580 V (the manual's example), configured at the
    nominal 1.5 V, on the fake Contec; ``force_fn(t)`` is the load (N) at bench time t."""
    bench_mod = load_fake("bench")
    bench = bench_mod.FakeBench(speed=20.0)
    inner = bench_mod.leptrino_analog_wiring(bench, {"Fx": 0}, {"Fx": 500.0},
                                             rest_V={"Fx": 1.580})
    wiring = {0: lambda t, f: inner[0](t, force_fn(t))}
    lib = load_fake("fake_caio").FakeCaioLibrary(bench, wiring=wiring)
    return bench, lib, CaioAcquisition(CAL, lib=declare(lib))


def _read(acq, n):
    out = []
    while sum(len(c.force_N) for c in out) < n:
        c = acq.read(1.0)
        assert c is not None, "no samples"
        out.append(c)
    return np.concatenate([c.force_N for c in out])[:n]


def test_a_sensor_resting_off_nominal_reads_zero_after_the_automatic_tare(fake_mcs):
    bench, _lib, acq = _resting_rig(fake_mcs, lambda t: np.zeros_like(t))
    try:
        acq.configure(2000.0)
        acq.start(400, triggered=False)
        force = _read(acq, 400)
        # untared, (1.580 - 1.5) V x 500 N/V = 40 N at rest; tared, within 1 N of zero
        assert np.abs(force).max() < 1.0
        assert acq._tare.no_load_V["Fx"] == pytest.approx(1.580, abs=1e-3)
    finally:
        acq.close()


def test_the_force_limit_trips_at_its_configured_force_on_the_tared_force(fake_mcs):
    # the load rises 20 N/s; untared it would trip at rest (40 N > 25 N); tared, at the
    # limit within 1 N
    true_N = true_load_at_trip(lambda load: _resting_rig(fake_mcs, load), 20.0, 25.0)
    assert abs(true_N - 25.0) < 1.0, true_N


def test_the_tare_is_due_before_the_first_block_and_after_each_rest():
    from nmsid.drivers.analog_force import REST_BEFORE_TARE_S, NoLoadTare
    now = [0.0]
    tare = NoLoadTare(clock=lambda: now[0])
    assert tare.due()                                   # before the session's first block
    tare.update(np.full((10, 1), 1.58), CAL, "test")
    assert not tare.due() and tare.wrench[0] == pytest.approx(40.0)
    tare.stopped()
    now[0] += 0.5 * REST_BEFORE_TARE_S                  # back-to-back blocks: keep it
    assert not tare.due()
    now[0] += REST_BEFORE_TARE_S                        # a rest: measure again
    assert tare.due()
    tare.update(np.full((10, 1), 1.55), CAL, "test")
    assert not tare.due()
    tare.forget()                                       # a reconnect
    assert tare.due()
    with pytest.raises(DeviceError, match="edge of its"):   # a sensor clipped at rest
        tare.update(np.full((10, 1), 3.3), CAL, "test")
