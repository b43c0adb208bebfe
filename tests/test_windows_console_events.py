"""Windows console control events end a session like the E-stop (issue 24, 3).

Run against nmsid.testing.fake_windows_api.FakeKernel32, which follows the documented
semantics of SetConsoleCtrlHandler: the routine runs on a new thread, last-registered
first, and for close / logoff / shutdown the process is ended when it returns (or 5 s
after a close event)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nmsid.protocols import os_platform
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig import session_signals
from nmsid.rig.session_log import journal_dir
from nmsid.rig.session_signals import CONSOLE_EVENTS, SessionSignals, signal_reason
from nmsid.testing.fake_windows_api import (
    CTRL_BREAK_EVENT,
    CTRL_C_EVENT,
    CTRL_CLOSE_EVENT,
    CTRL_LOGOFF_EVENT,
    CTRL_SHUTDOWN_EVENT,
    FakeKernel32,
)

ROOT = Path(__file__).resolve().parents[1]


def _windows(kernel32):
    class Both:
        def __enter__(self):
            self.a, self.b = os_platform.forced("windows"), os_platform.fake_windows_api(
                kernel32=kernel32)
            self.a.__enter__()
            self.b.__enter__()

        def __exit__(self, *exc):
            self.b.__exit__(*exc)
            self.a.__exit__(*exc)
    return Both()


def _wait_in_main_thread(calls, timeout_s=5.0):
    """The main thread as nmsid run keeps it: short waits, so handlers run between them."""
    t0 = time.monotonic()
    while not calls and time.monotonic() - t0 < timeout_s:
        threading.Event().wait(0.1)


@pytest.mark.parametrize("event, code", [(CTRL_C_EVENT, 130), (CTRL_BREAK_EVENT, 149)])
def test_ctrl_c_and_ctrl_break_call_the_estop_in_the_main_thread(event, code):
    k = FakeKernel32()
    calls = []
    with _windows(k):
        with SessionSignals(lambda s, r: calls.append(
                (s, r, threading.current_thread() is threading.main_thread()))) as sig:
            assert len(k.handlers) == 1
            k.deliver(event).join(2)
            _wait_in_main_thread(calls)
        assert k.handlers == []  # removed with the session
    name = CONSOLE_EVENTS[event].name
    assert calls == [(CONSOLE_EVENTS[event], signal_reason(CONSOLE_EVENTS[event]), True)]
    assert calls[0][1].startswith(f"{name} received (Ctrl+")
    assert k.terminated_with is None  # handled: the command ends itself
    assert sig.exit_code == code
    assert sig.stderr_line("s.h5").startswith(f"nmsid: {name} received: E-stop, output off")


@pytest.mark.parametrize("event", [CTRL_CLOSE_EVENT, CTRL_LOGOFF_EVENT, CTRL_SHUTDOWN_EVENT])
def test_close_logoff_shutdown_hold_termination_until_the_session_is_closed(event):
    k = FakeKernel32()
    calls = []
    with _windows(k):
        with SessionSignals(lambda s, r: calls.append(r)) as sig:
            thread = k.deliver(event)
            _wait_in_main_thread(calls)
            time.sleep(0.2)  # the session is still closing: the process must live on
            assert k.terminated_with is None and thread.is_alive()
        thread.join(2)
    assert k.terminated_with == 0xC000013A  # ended once the routine returned
    assert calls == [signal_reason(CONSOLE_EVENTS[event])]
    assert sig.exit_code == 129


def test_a_close_event_ends_the_process_after_five_seconds_if_the_session_hangs():
    k = FakeKernel32(close_timeout_s=0.3)  # the system's 5 s, shortened
    with _windows(k), SessionSignals(lambda s, r: None):
        t0 = time.monotonic()
        k.deliver(CTRL_CLOSE_EVENT)
        while k.terminated_with is None and time.monotonic() - t0 < 3:
            time.sleep(0.01)
        assert 0.25 < time.monotonic() - t0 < 1.0
    assert session_signals.TERMINATING_WAIT_S < 5.0  # ours returns before the system's


def test_the_routine_runs_first_and_previous_handlers_come_back():
    k = FakeKernel32()
    earlier = []
    k.SetConsoleCtrlHandler(lambda e: earlier.append(e) or 1, 1)  # e.g. Python's own
    before = signal.getsignal(signal.SIGINT)
    calls = []
    with _windows(k):
        with SessionSignals(lambda s, r: calls.append(s)):
            k.deliver(CTRL_C_EVENT).join(2)
            _wait_in_main_thread(calls)
        k.deliver(CTRL_C_EVENT).join(2)  # after the session: the earlier routine again
    assert len(calls) == 1 and earlier == [CTRL_C_EVENT]
    assert signal.getsignal(signal.SIGINT) is before


_CHILD = """
import os, sys, threading, time
from pathlib import Path
from nmsid.protocols import os_platform
from nmsid.rig.session_log import journal_dir
from nmsid.testing.fake_windows_api import FakeKernel32, msvcrt_here
event, args = int(sys.argv[1]), sys.argv[2:]
k = FakeKernel32(terminate=lambda code: os._exit(code & 0xFF))
stream = journal_dir(Path(args[args.index("--out") + 1])) / "partial.f64"
def watch():
    while not (stream.exists() and stream.stat().st_size >= 8 * 11 * 400):
        time.sleep(0.01)
    k.deliver(event)
threading.Thread(target=watch, daemon=True).start()
with os_platform.forced("windows"), os_platform.fake_windows_api(kernel32=k,
                                                                msvcrt=msvcrt_here()):
    from nmsid.cli import main
    code = main(args)
sys.exit(code)
"""


@pytest.mark.parametrize("event", [CTRL_CLOSE_EVENT, CTRL_C_EVENT])
def test_a_console_event_ends_a_real_nmsid_run_like_the_estop(tmp_path, event):
    cfg = tmp_path / "c.toml"
    cfg.write_text('participant = "SG"\n[protocol]\nsE_levels = [0.5, 0.7]\nrepeats = 1\n'
                   'steady_s = 1.0\nchirp_s = 3.0\n[calibration]\nmanual = {Iemin_mA = 2.0, '
                   'Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n', encoding="utf-8")
    out = tmp_path / "s.h5"
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, str(event), "run", "--backend", "sim", "--realtime",
         "--config", str(cfg), "--out", str(out), "--no-identify"],
        check=False, capture_output=True, text=True, cwd=str(ROOT), timeout=120,
        env=dict(os.environ, PYTHONUNBUFFERED="1"))
    ev = CONSOLE_EVENTS[event]
    if event == CTRL_CLOSE_EVENT:
        # the system ends the process once the routine returns (the session closed): the
        # command may or may not have printed its line and exited first
        assert proc.returncode in (129, 0xC000013A & 0xFF), proc.stderr
        assert len(proc.stderr.splitlines()) <= 1, proc.stderr   # at most its one line
    else:
        assert proc.returncode == 130, proc.stderr
        assert proc.stderr.splitlines() == [proc.stderr.strip()]
        assert proc.stderr.startswith(f"nmsid: {ev.name} received: E-stop, output off")
    assert validate_session(out) == [] and not journal_dir(out).exists()
    s = read_session(out)
    reason = signal_reason(ev)
    assert len(s.trials) == 1 and s.trials[0].abort_reason == f"estop: {reason}"
    kinds = [e.kind for e in s.events]
    trip = kinds.index("interlock_trip")
    assert reason in s.events[trip].detail
    assert trip < kinds.index("trial_aborted") < kinds.index("session_end")


def test_stop_output_runs_on_the_routines_thread_before_the_main_thread():
    k = FakeKernel32()
    order = []
    with _windows(k), SessionSignals(
            lambda s, r: order.append(("on_signal", threading.current_thread().name)),
            lambda r: order.append(("stop_output", threading.current_thread().name))):
        k.deliver(CTRL_CLOSE_EVENT)
        t0 = time.monotonic()
        while len(order) < 2 and time.monotonic() - t0 < 5:
            threading.Event().wait(0.05)
    assert [o[0] for o in order] == ["stop_output", "on_signal"]
    assert order[0][1].startswith("console-handler-") and order[1][1] == "MainThread"
