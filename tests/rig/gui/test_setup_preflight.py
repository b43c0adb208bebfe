"""The GUI's Start runs the CLI's preflight before any device (issue 26, 6): an output
folder that cannot be written, a name too long for the journal's derived names, a seed
the CLI would refuse; operator mistakes are one line, never a traceback; the window gives
a finished session's freed memory back."""

from __future__ import annotations

import logging
import os
import platform

import pytest

from nmsid.protocols.os_platform import forced
from nmsid.protocols.user_values import MAX_SESSION_NAME_BYTES


def _panel(qtbot):
    from nmsid.rig.gui.setup_panel import SetupPanel
    got = []
    p = SetupPanel(on_start=got.append)
    qtbot.addWidget(p)
    return p, got


@pytest.mark.posix_only("a read-only folder is POSIX permission bits; Windows ignores a folder's "
                        "read-only attribute (Python docs, os.access), so nmsid tries to create a "
                        "file there instead")
def test_a_read_only_output_folder_is_refused_before_start(qtbot, tmp_path, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    real_access = os.access
    # tests may run as root (which writes anywhere): the folder says "not writable"
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False
                        if os.path.abspath(p) == str(folder) else real_access(p, mode, **kw))
    p, got = _panel(qtbot)
    p.set_values(participant="P01", output=folder / "P01.h5")
    assert not p.start_button.isEnabled()
    assert "cannot write in" in p.message.text()
    p.press_start()
    assert got == []                                     # nothing handed on: no device


def test_an_output_under_a_file_is_refused_before_start(qtbot, tmp_path):
    (tmp_path / "afile").write_text("x", encoding="utf-8")
    p, got = _panel(qtbot)
    p.set_values(participant="P01", output=tmp_path / "afile" / "P01.h5")
    p.press_start()
    assert got == [] and not p.start_button.isEnabled()
    assert "not a folder" in p.message.text()


def test_a_name_too_long_for_the_journal_is_refused_before_start(qtbot, tmp_path):
    p, got = _panel(qtbot)
    p.set_values(participant="P01",
                 output=tmp_path / ("a" * (MAX_SESSION_NAME_BYTES - 2) + ".h5"))
    p.press_start()
    assert got == [] and "bytes long" in p.message.text()
    p.set_values(output=tmp_path / ("a" * (MAX_SESSION_NAME_BYTES - 3) + ".h5"))
    p.press_start()
    assert len(got) == 1


@pytest.mark.parametrize("text, seed", [("", None), ("0", 0), ("9999999999", 9999999999),
                                        (str(2 ** 63 - 1), 2 ** 63 - 1)])
def test_the_seed_field_takes_what_the_cli_takes(qtbot, tmp_path, text, seed):
    p, got = _panel(qtbot)
    p.set_values(participant="P01", output=tmp_path / "s.h5")
    p.seed.setText(text)
    p.press_start()
    assert len(got) == 1 and got[0].seed == seed


@pytest.mark.parametrize("text", ["-1", str(2 ** 63), "abc", "1.5"])
def test_the_seed_field_refuses_what_the_cli_refuses(qtbot, tmp_path, text):
    p, got = _panel(qtbot)
    p.set_values(participant="P01", output=tmp_path / "s.h5")
    p.seed.setText(text)
    p.press_start()
    assert got == [] and not p.start_button.isEnabled()
    assert "seed" in p.message.text() and "[0, 9223372036854775807]" in p.message.text() \
        or "whole number" in p.message.text()


def test_a_start_refused_by_the_rig_is_one_line_not_a_traceback(qtbot, tmp_path, caplog):
    from nmsid.errors import SafetyError
    from nmsid.rig.gui.setup_panel import SetupPanel

    def refuse(request):
        raise SafetyError("ceiling 40 mA is above the stimulator's 16 mA\n(second line)")

    p = SetupPanel(on_start=refuse)
    qtbot.addWidget(p)
    p.set_values(participant="P01", output=tmp_path / "s.h5")
    with caplog.at_level(logging.ERROR):
        p.press_start()                                  # raises nothing into Qt
    assert "ceiling 40 mA" in p.message.text() and "\n" not in p.message.text()
    assert all(r.exc_info is None for r in caplog.records)


def test_freed_memory_is_given_back_through_the_platform_switch():
    from nmsid.rig.gui.memory import release_freed_memory
    with forced("windows"):
        assert release_freed_memory() is False           # no malloc_trim on Windows
    if platform.libc_ver()[0] == "glibc":
        with forced("posix"):
            assert release_freed_memory() is True        # malloc_trim(0) asked


@pytest.mark.parametrize("make_error, code, traceback", [
    (lambda: ValueError("no aborted trial to re-run"), 2, False),
    (lambda: __import__("nmsid.errors").errors.SafetyError("interlock latched"), 4, False),
    (lambda: KeyError("a bug"), 1, True),
])
def test_a_failed_script_step_is_one_line_and_exits_as_the_readme_says(
        fake_window, qtbot, caplog, monkeypatch, make_error, code, traceback):
    from nmsid.rig.gui.script import ScriptRunner, parse_script

    def fail(*a, **kw):
        raise make_error()

    monkeypatch.setattr(fake_window, "rerun", fail)
    runner = ScriptRunner(fake_window, parse_script("rerun 1\n", "t"), parent=fake_window)
    with caplog.at_level(logging.ERROR):
        runner.start()
        qtbot.waitUntil(lambda: runner.done, timeout=5000)
    assert runner.ok is False and runner.exit_code == code
    failed = [r for r in caplog.records if "GUI script failed" in r.getMessage()]
    assert len(failed) == 1 and (failed[0].exc_info is not None) is traceback
