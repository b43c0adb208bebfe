"""SIGTERM, SIGHUP and SIGINT end a real `nmsid run` process the way the E-stop does.

Real processes, real signals (``os.kill``), a real-time simulated session: the output is
zeroed first (the interlock's ``estop`` trip names the signal), the trial in progress is
aborted with that reason, the session has its ``session_end`` record, the file is valid,
the exit status is 128 + the signal number and stderr holds exactly one line.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.session_log import journal_dir
from nmsid.rig.session_signals import SessionSignals, exit_code, signal_reason

ROOT = Path(__file__).resolve().parents[2]
TRIAL = ('participant = "SG"\n[protocol]\nsE_levels = [0.5, 0.7]\nrepeats = 1\n'
         'steady_s = 1.0\nchirp_s = 3.0\n[calibration]\nmanual = {Iemin_mA = 2.0, '
         'Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n')
CALIBRATION = ('participant = "SC"\n[protocol]\nsE_levels = [0.5]\nrepeats = 1\n'
               'steady_s = 1.0\nchirp_s = 2.0\n[calibration]\nhold_s = 0.5\n'
               'baseline_s = 0.3\nrest_s = 0.3\n')

#: Sending a signal to a process: POSIX only. On Windows os.kill(pid, SIGTERM) is
#: TerminateProcess (uncatchable) and Ctrl-C / Ctrl-Break / close are console events
#: (tests/test_windows_console_events.py).
posix_signals = pytest.mark.skipif(
    not hasattr(signal, "SIGHUP"), reason="POSIX signals: on Windows os.kill is "
    "TerminateProcess and Ctrl-C a console event (test_windows_console_events.py)")


def _start(tmp_path, config_text, out):
    cfg = tmp_path / "c.toml"
    cfg.write_text(config_text)
    return subprocess.Popen(
        [sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim", "--realtime",
         "--config", str(cfg), "--out", str(out), "--no-identify"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=str(ROOT),
        env=dict(os.environ, PYTHONUNBUFFERED="1"))


def _wait_for(proc, ready, timeout_s=60.0):
    t0 = time.monotonic()
    while proc.poll() is None and time.monotonic() - t0 < timeout_s and not ready():
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()


def _ended(proc, signum):
    out, err = proc.communicate(timeout=60)
    lines = err.decode().splitlines()
    assert proc.returncode == exit_code(signum) == 128 + signum, (out, err)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"nmsid: {signal.Signals(signum).name} received")
    return out.decode(), lines[0]


@posix_signals
@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP", "SIGINT"])
def test_signal_during_a_trial_is_an_estop(tmp_path, name):
    signum = getattr(signal, name)  # SIGHUP: POSIX only, not looked up at import
    out = tmp_path / "s.h5"
    proc = _start(tmp_path, TRIAL, out)
    stream = journal_dir(out) / "partial.f64"
    # the first trial has streamed a few chunks (real time)
    # 11 columns of float64
    _wait_for(proc, lambda: stream.exists() and stream.stat().st_size >= 8 * 11 * 400)
    os.kill(proc.pid, signum)
    _, line = _ended(proc, signum)
    assert str(out) in line and "--resume" in line
    assert validate_session(out) == [] and not journal_dir(out).exists()
    s = read_session(out)
    reason = signal_reason(signum)
    assert len(s.trials) == 1 and not s.trials[0].completed
    assert s.trials[0].abort_reason == f"estop: {reason}"
    assert 400 <= s.trials[0].n_samples < 8000
    kinds = [e.kind for e in s.events]
    # output zeroed (the E-stop trip) before the trial's abort record, then the end record
    trip = kinds.index("interlock_trip")
    assert reason in s.events[trip].detail
    assert trip < kinds.index("trial_aborted") < kinds.index("session_end")
    assert reason in s.events[kinds.index("session_end")].detail


@posix_signals
def test_sigterm_during_calibration_stops_output_and_writes_nothing_half(tmp_path):
    out = tmp_path / "c.h5"
    proc = _start(tmp_path, CALIBRATION, out)
    jdir = journal_dir(out)
    # calibration is running: the journal exists, the calibration is not known yet
    _wait_for(proc, lambda: (jdir / "events.jsonl").exists())
    time.sleep(0.3)
    assert not (jdir / "calibration.npz").exists()
    os.kill(proc.pid, signal.SIGTERM)
    stdout, line = _ended(proc, signal.SIGTERM)
    # no calibration, so no session file; the journal records the E-stop and the end
    assert not out.exists()
    # issue 39: the line named a closed file that did not exist; the first line of a run
    # comes before its calibration ends (a real-time run said nothing for 25 s)
    assert "no session file was written" in line and "--resume" not in line
    assert "starting: 0 of 1 trials done" in stdout
    events = (jdir / "events.jsonl").read_text()
    assert "SIGTERM received" in events and "session_end" in events
    assert events.index("interlock_trip") < events.index("session_end")


def test_the_line_says_what_was_saved_and_offers_a_resume_only_when_it_applies():
    """Issue 39: SIGINT after 45 of 45 trials said "continue with nmsid run --resume"."""
    sig = SessionSignals(lambda *a: None)
    sig.received = signal.SIGINT
    assert "--resume s.h5" in sig.stderr_line("s.h5")
    done = sig.stderr_line("s.h5", complete=True)
    assert "session complete and closed: s.h5" in done and "--resume" not in done
    assert "nmsid identify s.h5" in done
    none = sig.stderr_line("s.h5", file_written=False)
    assert "no session file was written" in none and "closed" not in none
    assert sig.stderr_line().endswith("no session was running")


def test_no_signal_handlers_left_behind_in_process(tmp_path):
    from nmsid.cli import main

    cfg = tmp_path / "c.toml"
    cfg.write_text(TRIAL.replace("chirp_s = 3.0", "chirp_s = 0.5"))

    names = ("SIGINT", "SIGTERM", "SIGHUP", "SIGBREAK")  # those this system has
    before = {getattr(signal, n): signal.getsignal(getattr(signal, n)) for n in names
              if hasattr(signal, n)}
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out",
                 str(tmp_path / "x.h5"), "--no-identify", "--quiet"]) == 0
    assert {s: signal.getsignal(s) for s in before} == before


@posix_signals
def test_sigterm_ends_a_gui_session_like_the_estop(tmp_path):
    pytest.importorskip("PySide6")
    cfg = tmp_path / "c.toml"
    cfg.write_text(TRIAL)
    out = tmp_path / "g.h5"
    script = tmp_path / "s.txt"
    script.write_text(f"start participant=SG output={out}\nconfirm-calibration\n"
                      "wait-trial 0 running 60\n"
                      "wait-trial-time 0.3 60\nsleep 60\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "nmsid.cli", "gui", "--config", str(cfg), "--script",
         str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=str(ROOT),
        env=dict(os.environ, PYTHONUNBUFFERED="1", QT_QPA_PLATFORM="offscreen"))
    stream = journal_dir(out) / "partial.f64"
    _wait_for(proc, lambda: stream.exists() and stream.stat().st_size >= 8 * 11 * 600, 120)
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    # Qt's offscreen platform prints its own notes; nmsid's is one line, the last
    ours = [ln for ln in err.decode().splitlines() if ln.startswith("nmsid")]
    assert len(ours) == 1 and ours[0] == err.decode().splitlines()[-1], err
    assert ours[0].startswith("nmsid: SIGTERM received: E-stop") and str(out) in ours[0]
    assert validate_session(out) == []
    s = read_session(out)
    assert [t.abort_reason for t in s.trials] == ["estop: SIGTERM received"]
    assert s.events[-1].kind == "session_end" and "SIGTERM" in s.events[-1].detail
