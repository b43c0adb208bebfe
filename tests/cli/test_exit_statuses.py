"""Exit statuses as the README says (1 is only a bug): a run ended by an interlock trip is
4, ``recover`` with no data to recover is 2; the GUI and the CLI bound seeds the same."""

from __future__ import annotations

import argparse

import pytest

from nmsid.cli import main
from nmsid.cli.arguments import seed
from nmsid.cli.exit_status import run_exit_status
from nmsid.errors import EXIT_USER_ERROR, DeviceFault, SafetyError
from nmsid.protocols.session_file import SessionWriter, read_session
from nmsid.protocols.user_values import MAX_SESSION_NAME_BYTES, parse_seed

TRIP = ("[protocol]\nsE_levels = [0.4, 0.6]\nrepeats = 1\nsteady_s = 1.0\nchirp_s = 2.0\n"
        "[calibration]\nmanual = {Iemin_mA = 2.0, Iemax_mA = 9.5, Ifmin_mA = 1.5, "
        "Ifmax_mA = 8.0}\n[interlock]\nforce_limit_N = 0.05\n")


def test_a_run_ended_by_an_interlock_trip_exits_4(tmp_path, capsys):
    cfg = tmp_path / "trip.toml"
    cfg.write_text(TRIP, encoding="utf-8")
    out = tmp_path / "T.h5"
    code = main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--quiet", "--no-identify"])
    assert code == SafetyError.exit_code == 4
    assert "interlock: force_limit" in capsys.readouterr().out
    assert read_session(out).trials[0].status == "aborted"


class _Summary:
    def __init__(self, ended_by):
        self.ended_by = ended_by


@pytest.mark.parametrize("ended_by, code", [
    ("schedule complete", 0),
    ("interlock: charge_balance: the waveform is not charge-balanced", SafetyError.exit_code),
    ("interlock: force_limit: force 30 N", SafetyError.exit_code),
    ("stimulator unplugged; session ended for --resume", DeviceFault.exit_code),
    ("aborted by operator", 0),
])
def test_run_exit_status_follows_how_the_session_ended(ended_by, code):
    assert run_exit_status(_Summary(ended_by)) == code


def test_recover_with_no_data_to_recover_exits_2(tmp_path, capsys):
    path = tmp_path / "N.h5"
    SessionWriter.create(path, participant="P01")          # ended before its calibration
    (tmp_path / "N.h5.journal").mkdir()
    assert main(["recover", str(path)]) == EXIT_USER_ERROR
    assert "no data to recover" in capsys.readouterr().out


@pytest.mark.parametrize("text, value", [("0", 0), ("9999999999", 9999999999),
                                         (str(2 ** 63 - 1), 2 ** 63 - 1)])
def test_cli_and_gui_accept_the_same_seeds(text, value):
    assert seed(text) == value
    assert parse_seed(text, empty_is_random=True) == (value, None)


@pytest.mark.parametrize("text", ["-1", str(2 ** 63), "x", "1.5"])
def test_cli_and_gui_refuse_the_same_seeds(text):
    with pytest.raises(argparse.ArgumentTypeError):
        seed(text)
    value, problem = parse_seed(text, empty_is_random=True)
    assert value is None and problem and "\n" not in problem


def test_an_empty_gui_seed_is_random_and_the_cli_says_so_by_leaving_it_out():
    assert parse_seed("", empty_is_random=True) == (None, None)
    with pytest.raises(argparse.ArgumentTypeError):
        seed("")


def test_the_longest_session_name_leaves_room_for_every_derived_name(tmp_path):
    # the derived names are real: build each beside a name of the maximum length
    name = "s" * (MAX_SESSION_NAME_BYTES - 3) + ".h5"
    for suffix in (".journal.headerless-20261124T234000Z-999", ".damaged-20261124T234000Z-999",
                   ".journal.done-4294967295", ".writing-4294967295", ".lock"):
        (tmp_path / (name + suffix)).write_bytes(b"")       # fits NAME_MAX (255 bytes)
    (tmp_path / (".nmsid-tmp-" + name + "-old-4294967295")).write_bytes(b"")
    with pytest.raises(SystemExit) as exc:                   # one byte more: refused
        main(["run", "--backend", "sim", "--out", str(tmp_path / ("s" + name))])
    assert exc.value.code == EXIT_USER_ERROR
