"""The README works as written (issue 39, 2): every command block of README.md runs, in
order, in a fresh temporary folder, on the simulated rig, as a newcomer would type it.

A block is skipped only when the line before it says why (``<!-- readme-test: skip: ... -->``:
hardware, a window, an hour of real time), or when it is the opening ``python3 dev.py``
block (it creates ``.venv`` and runs this very suite). Each line runs in ``bash`` (so the
README's globs expand as in a terminal) with ``nmsid`` being this interpreter's
``python -m nmsid``; each must exit 0. Timeouts are generous (10 min a line): a loaded
machine makes the commands slower, never wrong.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SKIP = re.compile(r"<!--\s*readme-test:\s*skip:\s*(.+?)\s*-->")
#: The opening block: it builds .venv/ and runs the suite this test belongs to.
DEV_BLOCK_REASON = "python3 dev.py creates .venv/ and runs the test suite this test is part of"
LINE_TIMEOUT_S = 600

pytestmark = pytest.mark.skipif(
    sys.platform == "win32" or shutil.which("bash") is None,
    reason="the README's blocks are POSIX shell lines (globs expanded by the shell)")


def readme_blocks(text: str) -> list[tuple[list[str], str | None]]:
    """Each ```sh block of ``text``: its command lines and, if skipped, why."""
    blocks: list[tuple[list[str], str | None]] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```sh":
            before = next((ln for ln in reversed(lines[:i]) if ln.strip()), "")
            j = i + 1
            while lines[j].strip() != "```":
                j += 1
            commands = [ln for ln in lines[i + 1:j] if ln.strip() and
                        not ln.lstrip().startswith("#")]
            why = SKIP.search(before)
            reason = why.group(1) if why else None
            if reason is None and all(c.startswith("python3 dev.py") for c in commands):
                reason = DEV_BLOCK_REASON
            blocks.append((commands, reason))
            i = j
        i += 1
    return blocks


def test_the_blocks_are_found_and_every_skip_says_why():
    blocks = readme_blocks(README.read_text(encoding="utf-8"))
    run = [c for c, why in blocks if why is None]
    skipped = [why for c, why in blocks if why is not None]
    assert sum(len(c) for c in run) >= 15          # the tour
    assert DEV_BLOCK_REASON in skipped and all(skipped)
    # what needs hardware or a window is never run here, and is marked as such
    for commands, why in blocks:
        text = " ".join(commands)
        if "--backend hw" in text or "nmsid gui" in text or "nmsid probe" in text:
            assert why is not None, commands


@pytest.mark.timeout(3600)
def test_every_command_block_runs_in_order_in_a_fresh_folder(tmp_path):
    work = tmp_path / "fresh"
    work.mkdir()
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "nmsid"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m nmsid "$@"\n', encoding="utf-8")
    shim.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
               MPLBACKEND="Agg", QT_QPA_PLATFORM="offscreen", PYTHONUNBUFFERED="1")
    ran = []
    for commands, why in readme_blocks(README.read_text(encoding="utf-8")):
        if why is not None:
            continue
        for line in commands:
            done = subprocess.run(["bash", "-c", line], cwd=work, env=env, text=True,
                                  capture_output=True, timeout=LINE_TIMEOUT_S)
            assert done.returncode == 0, (
                f"README line failed (exit {done.returncode}): {line}\n"
                f"stdout: {done.stdout[-2000:]}\nstderr: {done.stderr[-2000:]}")
            ran.append((line, done.stdout, done.stderr))
    # what the tour promises, checked on its own outputs
    selection = json.loads((work / "results" / "model_selection.json").read_text())
    assert selection["participants"] == ["P01"]     # two sessions, one participant
    twin = json.loads((work / "results" / "twin.json").read_text())
    assert len(twin["source"]) == 2 and twin["calibration"]
    design = next(out for line, out, _ in ran if line.startswith("nmsid design"))
    assert re.search(r"^verdict: (PASS|UNDECIDED|FAIL|NOT VALIDATED): ", design, re.M)
    assert len(list((work / "nwb").glob("P01-*.nwb"))) == 3
    assert list(work.glob("sessions/MSK01-*.h5"))
    for folder in ("results", "gap", "design", "ctl", "report", "nwb", "study"):
        assert (work / folder / ".nmsid-output.json").is_file(), folder
