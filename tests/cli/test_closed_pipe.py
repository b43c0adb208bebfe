"""``nmsid ... | head``: a reader that goes away ends the command quietly, and
``nmsid --version``. Real processes: the broken pipe is met by the interpreter's own stdout."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from nmsid.cli import EXIT_CLOSED_PIPE, main
from nmsid.protocols.session_file import read_session


def _run_into_closed_pipe(args: list[str], timeout_s: float = 120.0):
    """Run ``python -m nmsid ARGS`` with stdout a pipe whose read end is already closed
    (what ``| head`` leaves once head has exited): every write fails with EPIPE."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run([sys.executable, "-m", "nmsid", *args], stdout=write_end,
                              stderr=subprocess.PIPE, timeout=timeout_s)
    finally:
        os.close(write_end)


def test_a_handler_printing_into_a_closed_pipe_ends_quietly():
    # `nmsid twin` (no sub-command) prints its usage from the handler, and keeps its own
    # status (2: a usage error) over the closed pipe's
    done = _run_into_closed_pipe(["twin"])
    assert done.stderr == b""
    assert done.returncode == 2


def test_a_long_output_into_a_closed_pipe_ends_quietly(demo_session, tmp_path):
    # identify prints its tables (several kB) after writing the outputs
    done = _run_into_closed_pipe(["identify", str(demo_session), "--no-figures",
                                  "--out", str(tmp_path / "out")])
    assert b"internal error" not in done.stderr and b"Traceback" not in done.stderr
    assert done.stderr == b""
    assert done.returncode == EXIT_CLOSED_PIPE
    assert (tmp_path / "out" / "parameters.csv").exists()  # the work itself was done


SHORT = """
participant = "C01"
[protocol]
sE_levels = [0.4, 0.8]
repeats = 1
steady_s = 0.5
chirp_s = 1.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""


def test_a_session_whose_output_is_not_read_runs_to_its_end(tmp_path):
    # the progress lines come from the engine's thread: a closed pipe must not end the
    # session nor fill stderr with a traceback per trial
    config = tmp_path / "short.toml"
    config.write_text(SHORT)
    out = tmp_path / "s.h5"
    done = _run_into_closed_pipe(["run", "--backend", "sim", "--config", str(config),
                                  "--out", str(out), "--seed", "3", "--no-identify"])
    assert b"Traceback" not in done.stderr and b"Broken pipe" not in done.stderr
    assert done.returncode == EXIT_CLOSED_PIPE
    session = read_session(out)
    assert [t.status for t in session.trials] == ["completed", "completed"]


def test_help_into_a_closed_pipe_ends_quietly():
    done = _run_into_closed_pipe(["--help"])
    assert done.stderr == b"" and done.returncode == 0


def test_version_prints_the_installed_version(capsys):
    import nmsid
    with pytest.raises(SystemExit) as ended:
        main(["--version"])
    assert ended.value.code == 0
    assert capsys.readouterr().out == f"nmsid {nmsid.__version__}\n"


class _Failing:
    def __init__(self, err: int):
        self.err = err

    def write(self, text):
        raise OSError(self.err, os.strerror(self.err))

    def flush(self):
        raise OSError(self.err, os.strerror(self.err))


def test_windows_closed_pipe_einval_counts_as_a_gone_reader_and_other_errors_do_not():
    import errno

    from nmsid.cli import _EscapingStream
    gone = _EscapingStream(_Failing(errno.EINVAL))   # Windows' C runtime: a closed pipe
    assert gone.write("x") == 1 and gone.closed_pipe
    gone.flush()
    full = _EscapingStream(_Failing(errno.ENOSPC))   # a full disk is not a gone reader
    with pytest.raises(OSError):
        full.write("x")
    assert not full.closed_pipe
