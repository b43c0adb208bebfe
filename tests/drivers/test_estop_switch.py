"""E-stop switch: pyserial modem lines (loop:// and a real pty) and a DAQ digital input."""

from __future__ import annotations

import os
import time

import pytest

from nmsid.drivers.errors import DeviceNotFound
from nmsid.drivers.estop_switch import NidaqEStop, SerialEStop


@pytest.mark.parametrize("line, out", [("CTS", "rts"), ("DSR", "dtr")])
def test_loop_released_pressed_released(line, out):
    sw = SerialEStop("loop://", line=line)
    sw.open()
    assert sw.is_pressed() is False          # loop closed: input asserted
    setattr(sw._ser, out, False)             # the NC switch opens the loop
    assert sw.is_pressed() is True
    setattr(sw._ser, out, True)
    assert sw.is_pressed() is False
    sw.close()


def test_lost_port_reads_pressed_then_reopens():
    sw = SerialEStop("loop://", reopen_interval_s=0.05)
    sw.open()
    sw._ser.close()                           # adapter pulled out
    assert sw.is_pressed() is True
    assert sw.is_pressed() is True            # within the reopen interval: still pressed
    time.sleep(0.06)
    assert sw.is_pressed() is False           # reopened, loop closed again
    sw.close()


def test_port_without_modem_lines_reads_pressed():
    master, slave = os.openpty()
    try:
        sw = SerialEStop(os.ttyname(slave))
        with pytest.raises(DeviceNotFound, match="ioctl"):  # no modem-control lines
            sw.open()
        assert sw.is_pressed() is True       # and it reads as pressed, never released
        sw.close()
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port():
    sw = SerialEStop("/dev/no-such-adapter")
    with pytest.raises(DeviceNotFound, match="/dev/no-such-adapter.*estop.port"):
        sw.open()
    assert sw.is_pressed() is True            # never opened: fail-safe
    with pytest.raises(ValueError, match="estop.line 'RI'"):
        SerialEStop("loop://", line="RI")


def test_daq_digital_input(fake_nidaqmx):
    state = fake_nidaqmx(di_lines={"Dev1/port0/line0": True})
    sw = NidaqEStop("Dev1/port0/line0", released_level=True)
    sw.open()
    assert sw.is_pressed() is False
    state.di_lines["Dev1/port0/line0"] = False
    assert sw.is_pressed() is True
    state.di_lines["Dev1/port0/line0"] = OSError("USB device removed")
    assert sw.is_pressed() is True
    sw.close()
    assert sw.is_pressed() is True            # closed: fail-safe
    with pytest.raises(DeviceNotFound, match="Dev7"):
        NidaqEStop("Dev7/port0/line0").open()
