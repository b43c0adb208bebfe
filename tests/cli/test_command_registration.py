"""A command line that names a sub-command registers only that command's module (start-up
of ``nmsid identify``); ``nmsid --help`` still registers every one."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nmsid.cli import COMMAND_MODULES, COMMAND_OF, _named_command, build_parser


def _commands(parser) -> set[str]:
    sub = next(a for a in parser._actions if a.dest == "command")
    return set(sub.choices)


def test_the_table_names_every_registered_command_and_its_module():
    assert set(COMMAND_OF) == _commands(build_parser())
    assert set(COMMAND_OF.values()) == set(COMMAND_MODULES)
    for command in COMMAND_OF:
        assert command in _commands(build_parser([command, "--help"]))


@pytest.mark.parametrize("argv, named", [
    (["identify", "s.h5"], "identify"), (["-v", "identify"], "identify"),
    (["-vv", "--debug", "gap"], "gap"), (["--verbose", "twin"], "twin"),
    (["--help"], None), (["nonsense", "identify"], None), ([], None),
])
def test_the_named_command_is_the_first_word_after_the_global_options(argv, named):
    assert _named_command(argv) == named


def test_identify_registers_only_its_own_module():
    code = ("import sys, nmsid.cli; p = nmsid.cli.build_parser(['identify', 's.h5']); "
            "print(sorted(m for m in sys.modules if m in nmsid.cli.COMMAND_MODULES))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "['nmsid.cli.identify']"


def test_an_unknown_command_is_refused_in_one_line_naming_the_choices(capsys):
    from nmsid.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["identfy", "s.h5"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "identify" in err and "gap" in err
