"""CAIO behaviour as Contec documents it (issue 16): each test failed on the old code.

Setters a device does not implement answer AIO_ERR_SYS_NOT_SUPPORTED (20001): logged and
tolerated for the range (PM10 only) and the memory type, any other error stays fatal; the
fake uses Contec's error numbers; after a USB glitch the driver re-inits for a new ID.
"""

from __future__ import annotations

import logging

import pytest

from nmsid.drivers.caio import CaioAcquisition
from nmsid.drivers.errors import DeviceError
from nmsid.drivers.fake_hardware import load_fake
from tests.drivers.test_caio import CAL, read_all, rig


@pytest.mark.parametrize("func", ["AioSetAiRangeAll", "AioSetAiMemoryType"])
def test_not_supported_setter_is_logged_and_tolerated(fake_mcs, caplog, func):
    bench, lib = rig(fake_mcs)
    lib.unsupported.add(func)
    acq = CaioAcquisition(CAL, lib=lib)
    try:
        with caplog.at_level(logging.WARNING, logger="nmsid.drivers.caio"):
            assert acq.configure(2000.0) == 2000.0
        assert acq.unsupported == [func]
        assert f"does not support {func} (error 20001" in caplog.text
        acq.start(20, triggered=False)
        assert sum(c.n for c in read_all(acq, 20, bench)) == 20
    finally:
        acq.close()


def test_range_other_than_the_fixed_one_is_refused_when_the_device_cannot_set_it(fake_mcs):
    bench, lib = rig(fake_mcs)
    lib.unsupported.add("AioSetAiRangeAll")
    acq = CaioAcquisition(CAL, lib=lib, ai_range="PM5")
    with pytest.raises(DeviceError, match="acquisition.caio.range = 'PM5'.*'PM10'"):
        acq.configure(2000.0)


def test_other_setter_errors_stay_fatal(fake_mcs):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib, ai_range="PM5")  # fake: +/-10 V only -> 21060
    with pytest.raises(DeviceError, match="AioSetAiRangeAll.*error 21060"):
        acq.configure(2000.0)


def test_fake_uses_contecs_error_numbers():
    fake = load_fake("fake_caio")
    assert fake.AIO_ERR_DLL_DEVICE_NAME == 10000
    assert fake.AIO_ERR_DLL_INVALID_ID == 10001
    assert fake.AIO_ERR_SYS_NOT_SUPPORTED == 20001
    assert fake.AIO_ERR_SYS_BOARD_EXECUTING == 20002


def test_reconnect_after_usb_glitch_gets_a_new_id_and_never_uses_the_stale_one(fake_mcs):
    bench, lib = rig(fake_mcs)
    acq = CaioAcquisition(CAL, lib=lib)
    try:
        acq.configure(2000.0)
        stale = acq._id.value
        acq.start(None, triggered=False)
        lib.unplug()
        assert acq.read(0.05).flags.sensor_fault
        lib.replug()
        n_calls = len(lib.calls)
        assert acq.reconnect(2000.0) == 2000.0
        assert acq._id.value != stale
        after = lib.calls[n_calls:]
        used_stale = [c for c in after if c[0] not in ("AioExit", "AioInit", "AioGetErrorString")
                      and len(c) > 1 and c[1] == stale]
        assert [c[0] for c in after].count("AioInit") == 1
        assert used_stale == []
        acq.start(40, triggered=False)
        chunks = read_all(acq, 40, bench)
        assert sum(c.n for c in chunks) == 40 and not any(c.flags.any for c in chunks)
    finally:
        acq.close()
