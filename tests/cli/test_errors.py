"""What ends a command: user errors in one line (exit 2), bugs with a traceback (exit 1)."""

from __future__ import annotations

import errno

import pytest

from nmsid.cli import main, report
from nmsid.drivers.errors import DeviceNotFound
from nmsid.errors import (
    EXIT_BUG,
    EXIT_DEVICE_FAULT,
    EXIT_SAFETY,
    EXIT_USER_ERROR,
    DeviceFault,
    MissingDependency,
    NmsidError,
    SafetyError,
    UserError,
)
from nmsid.protocols.errors import ConfigError
from nmsid.sim_backends.errors import DeviceStateError


def test_a_bug_inside_an_analysis_function_is_exit_1_with_its_traceback(
        tmp_path, monkeypatch, capsys, demo_session):
    import nmsid.analysis.run as run_module

    def broken(*args, **kwargs):
        raise ValueError("deliberate bug: not a user mistake")
    monkeypatch.setattr(run_module, "identify_session", broken)
    status = main(["identify", str(demo_session), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == EXIT_BUG
    assert "Traceback (most recent call last)" in err
    assert "deliberate bug: not a user mistake" in err
    assert err.rstrip().splitlines()[-1].startswith("nmsid: internal error in `nmsid identify`")


def test_a_bad_file_is_still_one_line_and_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not an HDF5 file at all")
    status = main(["identify", str(junk), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == EXIT_USER_ERROR
    assert len(err.strip().splitlines()) == 1 and str(junk) in err
    assert "Traceback" not in err


@pytest.mark.parametrize("exc,status", [
    (ConfigError("rig.toml", "protocol.hold_s", 1e5, "0 < hold_s <= 60"), EXIT_USER_ERROR),
    (MissingDependency("pythonnet is not installed"), EXIT_USER_ERROR),
    (FileNotFoundError(errno.ENOENT, "No such file or directory", "/no/such.h5"),
     EXIT_USER_ERROR),
    (DeviceNotFound("STG4002 serial 123 not connected"), EXIT_DEVICE_FAULT),
    (SafetyError("current above its ceiling"), EXIT_SAFETY),
    (ValueError("a builtin from our code is a bug"), EXIT_BUG),
    (KeyError("x"), EXIT_BUG),
    (RuntimeError("x"), EXIT_BUG),
    (OSError("an OSError without a path is not the user's"), EXIT_BUG),
    (DeviceStateError("start() before arm()"), EXIT_BUG),
])
def test_each_branch_has_its_exit_status(exc, status, capsys):
    assert report(exc, "run") == status
    err = capsys.readouterr().err
    assert (err == "") == (status == EXIT_BUG)
    if status != EXIT_BUG:
        assert len(err.strip().splitlines()) == 1


def test_the_hierarchy_keeps_its_builtin_bases():
    assert issubclass(UserError, ValueError) and issubclass(UserError, NmsidError)
    assert issubclass(DeviceFault, OSError) and issubclass(SafetyError, NmsidError)
    assert issubclass(MissingDependency, ImportError)
    assert not issubclass(DeviceStateError, NmsidError)  # a programming error
