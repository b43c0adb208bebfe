"""Parsing of GUI scripts and the command line around them."""

from __future__ import annotations

import pytest

from nmsid.rig.gui.script import DEMO_SCRIPT, Command, ScriptError, load_script, parse_script


def test_parses_commands_arguments_and_comments():
    steps = parse_script("""
        # comment line
        start participant=P07 output="my dir/P07.h5"   # trailing comment
        confirm-calibration Iemin_mA=2.5
        wait-trial 1 running 30
        estop
        note "electrode re-taped, ok"
        wait tripped 5
        rerun 1
        tab results
        screenshot out.png
    """, "s.txt")
    cmds = [s.command for s in steps]
    assert cmds == [Command.START, Command.CONFIRM_CALIBRATION, Command.WAIT_TRIAL,
                    Command.ESTOP, Command.NOTE, Command.WAIT, Command.RERUN, Command.TAB,
                    Command.SCREENSHOT]
    assert steps[0].kwargs == {"participant": "P07", "output": "my dir/P07.h5"}
    assert steps[1].kwargs == {"Iemin_mA": "2.5"}
    assert steps[4].args == ("electrode re-taped, ok",)
    assert steps[2].line == 5


def test_windows_paths_keep_their_backslashes():
    # a script written on Windows: shlex's POSIX mode read each backslash as an escape and
    # gave output=C:UserslabsessionsP07.h5 (issue 42)
    steps = parse_script(r"""
        start participant=P07 output=C:\Users\lab\sessions\P07.h5   # comment
        screenshot "C:\Program Files\nmsid\shot 1.png"
        note 'saved to D:\data\'
    """, "win.txt")
    assert steps[0].kwargs == {"participant": "P07",
                               "output": "C:\\Users\\lab\\sessions\\P07.h5"}
    assert steps[1].args == ("C:\\Program Files\\nmsid\\shot 1.png",)
    assert steps[2].args == ("saved to D:\\data\\",)


@pytest.mark.parametrize("text, message", [
    ("launch", "unknown command 'launch'"),
    ("wait sleeping", "unknown state 'sleeping'"),
    ("wait-trial 1 finished", "status must be pending, running, done or aborted"),
    ("tab plots", "unknown tab 'plots'"),
    ("start colour=red", "unknown setting"),
    ("confirm-calibration Iemin_mA=lots", "Iemin_mA = 'lots' is refused: a number"),
    ("start seed=-1", "seed = '-1' is refused: a value >= 0"),
    ("note", "needs a text"),
    ("estop now", "takes 0..0 arguments"),
    ('note "unclosed', "cannot parse"),
])
def test_refuses_bad_lines_naming_the_line(text, message):
    with pytest.raises(ScriptError, match=message) as info:
        parse_script("estop\n" + text, "bad.txt")
    assert "bad.txt:2" in str(info.value)


def test_demo_script_is_valid_and_file_errors_name_the_file(tmp_path):
    assert parse_script(DEMO_SCRIPT, "demo")
    assert load_script("demo")
    with pytest.raises(OSError, match="missing.txt"):
        load_script(str(tmp_path / "missing.txt"))


def test_cli_registers_gui_with_its_options():
    import argparse

    from nmsid.cli import gui as cli_gui
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    cli_gui.register(sub)
    args = parser.parse_args(["gui", "--backend", "sim", "--participant", "P01", "--out",
                              "x.h5", "--script", "demo", "--screenshot", "s.png", "--fast"])
    assert args.handler == "nmsid.cli.gui:run"
    assert (args.backend, args.participant, args.out, args.script, args.screenshot,
            args.fast) == ("sim", "P01", "x.h5", "demo", "s.png", True)


def test_screenshot_without_script_is_refused():
    from pathlib import Path

    from nmsid.rig.gui.app import GuiOptions, run_gui
    with pytest.raises(ValueError, match="--script"):
        run_gui(GuiOptions(screenshot=Path("x.png")))


def test_wait_aborted_parses_with_an_optional_timeout():
    steps = parse_script("wait-aborted\nwait-aborted 5\n", "t")
    assert [s.command for s in steps] == [Command.WAIT_ABORTED, Command.WAIT_ABORTED]
    with pytest.raises(ScriptError, match="t:1: wait-aborted: .* got 'soon'"):
        parse_script("wait-aborted soon\n", "t")
