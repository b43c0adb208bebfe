"""Leptrino behaviour as the vendor documents it (issue 16): each test failed on the old code.

Short product-information replies (older firmware), strict rate text, the driver's own
errors for parse failures, reserved status bits, external-input sync on the rising edge,
and reconnecting after a USB glitch through a NEW port handle.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from nmsid.drivers.errors import HardwareConfigError, ProtocolError
from nmsid.drivers.hw_config import load_hw_config
from nmsid.drivers.leptrino import NOMINAL_RATE_HZ, LeptrinoAcquisition, LeptrinoSensor
from nmsid.drivers.leptrino_protocol import (
    Frame,
    Status,
    parse_data_record,
    parse_product_info,
    parse_rate_text,
    parse_rated_values,
)
from tests.drivers.test_leptrino_driver import collect

RATED = (500.0, 500.0, 1000.0, 10.0, 10.0, 10.0)


def _info_frame(rate: bytes | None) -> Frame:
    data = b"PFS080YA501G6".ljust(16, b"\0") + b"LT000042" + b"1.07"
    if rate is not None:
        data += rate.ljust(6, b"\0")
    return Frame(bytes([4 + len(data), 0xFF, 0x2A, 0]) + data)


def test_product_info_without_rate_field_is_accepted_as_not_stated():
    info = parse_product_info(_info_frame(None))  # 28 data bytes (older firmware)
    assert (info.model, info.serial, info.firmware) == ("PFS080YA501G6", "LT000042", "1.07")
    assert info.rate_stated is False
    assert np.isnan(info.output_rate_Hz)


@pytest.mark.parametrize("text, rate", [("1200", 1200.0), ("1200Hz", 1200.0),
                                        ("1.2k", 1200.0), ("1.2kHz", 1200.0),
                                        ("1kHz", 1000.0), ("600 Hz", 600.0)])
def test_documented_rate_spellings_are_accepted(text, rate):
    assert parse_product_info(_info_frame(text.encode())).output_rate_Hz == rate
    assert parse_rate_text(text) == rate


@pytest.mark.parametrize("text", ["1k2", "12e2", "fast", "0Hz", "1.2.3"])
def test_loose_rate_text_is_refused_naming_device_and_reply(text):
    with pytest.raises(ProtocolError) as err:
        parse_product_info(_info_frame(text.encode()), "Leptrino on 'COM9'")
    assert "COM9" in str(err.value) and repr(text) in str(err.value)


def test_parse_errors_are_the_drivers_protocol_error_not_value_error():
    short = Frame(bytes([8, 0xFF, 0x2A, 0, 1, 2, 3, 4]))
    for parse in (parse_product_info, parse_rated_values, parse_data_record):
        with pytest.raises(ProtocolError) as err:
            parse(short)
        assert not isinstance(err.value, ValueError)


def test_reserved_status_bits_are_masked_off():
    data = bytes(12) + bytes([0, 0]) + bytes([0xFF, 0])  # every status bit set
    rec = parse_data_record(Frame(bytes([4 + len(data), 0xFF, 0x32, 0]) + data))
    assert int(rec.status) == 0x07               # specification 6.1: bits 3-7 reserved
    assert rec.status == (Status.ROM_ERROR | Status.SENSOR_FAULT | Status.OVER_RATED)
    assert not hasattr(rec, "temperature_raw")   # the two bytes after Mz are reserved


@pytest.mark.full_rate_measurement
def test_old_firmware_sensor_with_random_reserved_bits_connects_and_reads_force(
        leptrino_emulator, caplog):
    """Done-when of issue 16: no error, no flag, the nominal rate said in the log."""
    emu = leptrino_emulator(rated=RATED, rate_text=None, reserved_bits_random=True,
                            wrench_fn=lambda t: (12.5, 0.0, 0.0, 0.0, 0.0, 0.0))
    acq = LeptrinoAcquisition(LeptrinoSensor(emu.port, reply_timeout_s=0.3))
    try:
        with caplog.at_level(logging.INFO, logger="nmsid.drivers.leptrino"):
            info = acq.connect()
        assert info.rate_stated is False
        assert acq.configure(NOMINAL_RATE_HZ) == NOMINAL_RATE_HZ
        assert acq.measured_rate_Hz == pytest.approx(1200.0, rel=0.01)   # measured, not read
        assert "none" in acq.describe()["rate stated by the sensor"]
        acq.start(300, triggered=False)
        chunks = collect(acq, 300)
        force = np.concatenate([c.force_N for c in chunks])
        assert len(force) == 300
        np.testing.assert_allclose(force, 12.5, atol=0.05)
        assert [c.flags.detail for c in chunks if c.flags.any] == []
    finally:
        acq.close()


def test_sync_on_an_undefined_bit_is_refused(leptrino_emulator, tmp_path):
    # specification v1.13, 6.1: status bits 3-7 are reserved; no bit is an external input
    emu = leptrino_emulator(rated=RATED)
    with pytest.raises(HardwareConfigError, match="6.1"):
        LeptrinoAcquisition(LeptrinoSensor(emu.port), sync_on_external_input=True)
    cfg = tmp_path / "hw.toml"
    cfg.write_text("[rig]\nfake = true\n[acquisition]\nkind = \"leptrino\"\n"
                   "[acquisition.leptrino]\nport = \"COM5\"\nsync_on_external_input = true\n",
                   encoding="utf-8")
    with pytest.raises(HardwareConfigError) as err:     # one line, naming the setting
        load_hw_config(cfg)
    line = str(err.value)
    assert "sync_on_external_input" in line and "6.1" in line and "\n" not in line


def test_reserved_bits_and_bytes_start_nothing_and_flag_nothing(leptrino_emulator):
    # every reserved status bit (3-7) set and random reserved bytes after Mz: the trial
    # streams from the first record and no flag is raised
    emu = leptrino_emulator(rated=RATED, reserved_bits_random=True,
                            wrench_fn=lambda t: (12.5, 0.0, 0.0, 0.0, 0.0, 0.0))
    emu.status_fn = lambda t: 0xF8
    acq = LeptrinoAcquisition(LeptrinoSensor(emu.port, reply_timeout_s=0.3))
    try:
        acq.configure(1200.0)
        acq.start(50, triggered=False)
        chunks = collect(acq, 50)
        assert chunks[0].start_index == 0
        assert [c.flags.detail for c in chunks if c.flags.any] == []
        np.testing.assert_allclose(np.concatenate([c.force_N for c in chunks]), 12.5,
                                   atol=0.05)
    finally:
        acq.close()


def test_reconnect_after_usb_glitch_opens_a_new_handle(leptrino_emulator):
    emu = leptrino_emulator(rated=RATED)
    opened = []

    def factory(port, baud, timeout):
        from nmsid.drivers.leptrino import open_serial
        ser = open_serial(port, baud, timeout)
        opened.append(ser)
        return ser

    sensor = LeptrinoSensor(emu.port, reply_timeout_s=0.3, serial_factory=factory)
    acq = LeptrinoAcquisition(sensor)
    try:
        acq.configure(1200.0)
        acq.start(None, triggered=False)
        assert collect(acq, 20)
        emu.unplug()
        faults = [c for c in collect(acq, 1, 1.0) if c.flags.sensor_fault]
        assert faults, "a dead port must read as a sensor fault"
        acq.stop()
        emu.replug()
        assert acq.reconnect(1200.0) == 1200.0
        assert len(opened) == 2 and opened[1] is not opened[0]
        assert opened[0].is_open is False
        acq.start(100, triggered=False)
        chunks = collect(acq, 100)
        assert sum(c.n for c in chunks) == 100
        assert not any(c.flags.any for c in chunks)
    finally:
        acq.close()
