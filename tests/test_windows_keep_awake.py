"""The PC does not sleep during a Windows session (issue 24, 5): SetThreadExecutionState
(ES_CONTINUOUS | ES_SYSTEM_REQUIRED) at the engine's start, ES_CONTINUOUS at its end, both
on the engine's thread (the state belongs to the thread)."""

from __future__ import annotations

import logging
import threading

import pytest

from nmsid.cli import main
from nmsid.protocols import os_platform
from nmsid.rig.keep_awake import ES_CONTINUOUS, ES_SYSTEM_REQUIRED, SystemAwake
from nmsid.testing.fake_windows_api import FakeKernel32, FakeMsvcrt

CONFIG = ('participant = "KA"\n[protocol]\nsE_levels = [0.5]\nrepeats = 1\n'
          'steady_s = 0.2\nchirp_s = 0.3\n[calibration]\nmanual = {Iemin_mA = 2.0, '
          'Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n')


@pytest.mark.posix_only('stands in for Windows itself with FakeKernel32 (built on fcntl, which the '
                        'emulation blocks)')
def test_a_session_keeps_the_system_awake_on_the_engine_thread(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(CONFIG, encoding="utf-8")
    k = FakeKernel32()
    with os_platform.forced("windows"), os_platform.fake_windows_api(
            kernel32=k, msvcrt=FakeMsvcrt()):
        code = main(["run", "--backend", "sim", "--config", str(cfg), "--out",
                     str(tmp_path / "s.h5"), "--no-identify", "--quiet"])
    assert code == 0
    (on, t_on), (off, t_off) = k.execution_state_calls
    assert on == ES_CONTINUOUS | ES_SYSTEM_REQUIRED and off == ES_CONTINUOUS
    assert t_on == t_off != threading.main_thread().ident
    assert k.execution_state == ES_CONTINUOUS  # the system may sleep again


def test_nothing_is_asked_off_windows_and_a_failure_is_a_warning(caplog):
    k = FakeKernel32()
    with os_platform.forced("posix"), os_platform.fake_windows_api(kernel32=k), \
            SystemAwake() as awake:
        assert not awake.active
    assert k.execution_state_calls == []
    k.execution_state_fails = True
    with caplog.at_level(logging.WARNING), os_platform.forced("windows"), \
            os_platform.fake_windows_api(kernel32=k), SystemAwake() as awake:
        assert not awake.active
    assert "Windows may sleep" in caplog.text
    assert len(k.execution_state_calls) == 1  # no reset of a request never granted
