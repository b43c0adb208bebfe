"""A Windows path in a double-quoted TOML string is refused in one line naming the file and
line and saying to use single quotes (issue 24, 4)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nmsid.protocols.errors import ConfigError
from nmsid.protocols.settings_base import read_toml


def test_a_backslash_path_names_file_and_line_and_says_single_quotes(tmp_path):
    f = tmp_path / "hw.toml"
    f.write_text('participant = "X"\n\n[stimulator]\ndll = "C:\\Program Files\\MCS\\x.dll"\n',
                 encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        read_toml(f, ConfigError, what="configuration file (--config)")
    message = str(err.value)
    assert message.startswith(f"{f}: setting line 4 = ")
    assert 'dll = "C:\\Program Files\\MCS\\x.dll"' in message
    assert "single quotes ('C:\\Program Files\\...')" in message
    f.write_text("participant = \"X\"\n[stimulator]\ndll = 'C:\\Program Files\\MCS\\x.dll'\n",
                 encoding="utf-8")
    assert read_toml(f, ConfigError, what="x")["stimulator"]["dll"] == (
        "C:\\Program Files\\MCS\\x.dll")


def test_other_toml_errors_keep_their_message(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("participant = \n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        read_toml(f, ConfigError, what="x")


def test_the_command_line_prints_one_line(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('participant = "X"\nnote = "D:\\data\\P01"\n', encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "nmsid", "run", "--backend", "sim",
                           "--config", str(f), "--out", str(tmp_path / "s.h5")],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "line 2" in proc.stderr
    assert "single quotes" in proc.stderr and not (tmp_path / "s.h5").exists()


def test_a_drive_path_that_happens_to_parse_is_refused_too(tmp_path):
    """"C:\\temp\\new" is valid TOML (a tab and a newline), never the path typed."""
    f = tmp_path / "c.toml"
    f.write_text('participant = "X"\n# "C:\\in a comment" is fine\nout = "C:\\temp\\new"\n',
                 encoding="utf-8")
    with pytest.raises(ConfigError, match=r"setting line 3 = .*single quotes"):
        read_toml(f, ConfigError, what="x")
    f.write_text("participant = \"X\"\na = \"C:\\\\temp\"\nb = 'C:\\temp'\nc = \"C:/temp\"\n",
                 encoding="utf-8")
    assert read_toml(f, ConfigError, what="x") == {"participant": "X", "a": "C:\\temp",
                                                   "b": "C:\\temp", "c": "C:/temp"}
