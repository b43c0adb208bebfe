"""SIGKILL a tracking session (``nmsid run --track``) at random moments, then recover:
every trial reported completed is kept bit for bit, the interrupted one is closed as
aborted with its tracking attributes, and the file validates."""

import json
import os
import re
import signal
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from nmsid.analysis.control.design import design_controller
from nmsid.analysis.twin import Twin
from nmsid.cli import main
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.session_log import PARTIAL_ABORT_REASON, journal_dir, recover
from nmsid.sim_backends.participant import default_participant
from tests.rig.forked_cli import fork_main, wait_child

CONFIG = """
participant = "K02"
seed = 5
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""
# the progress line names the trial as the file does (issue 39 item 6: one numbering)
LINE = re.compile(r"^(t\d{3}) completed: sE (\S+) repeat (\d+) attempt (\d+) n \d+ "
                  r"crc ([0-9a-f]{8})")

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork / SIGKILL")


def _printed(log_path):
    text = Path(log_path).read_text(errors="replace") if Path(log_path).exists() else ""
    return [(m.group(1), m.group(5)) for m in map(LINE.match, text.splitlines()) if m]


def test_sigkill_a_tracking_session_loses_nothing_completed(tmp_path):
    import nmsid.cli.run_command  # noqa: F401  (import once here, not in every child)
    d = design_controller(Twin.from_dict(default_participant().to_twin()), levels=2)
    d.baseline["relay_s"] = 2.0
    d.save(tmp_path / "controller.json")
    (tmp_path / "k.toml").write_text(CONFIG, encoding="utf-8")
    (tmp_path / "target.csv").write_text("t_s,force_N\n0,0\n1,1.5\n2,-1\n", encoding="utf-8")

    def argv(out):
        return ["run", "--backend", "sim", "--config", tmp_path / "k.toml", "--out", out,
                "--track", tmp_path / "controller.json", "--target", tmp_path / "target.csv"]

    t0 = time.monotonic()
    pid = fork_main(argv(tmp_path / "ref.h5"), tmp_path / "ref.txt")
    code, _ = wait_child(pid)
    duration = time.monotonic() - t0
    assert code == 0, (tmp_path / "ref.txt").read_text()[-2000:]
    ref = dict(_printed(tmp_path / "ref.txt"))
    assert len(ref) == 3
    rng = np.random.default_rng(28)
    hit = resumed = 0
    for k in range(2):
        path, log = tmp_path / f"k{k}.h5", tmp_path / f"k{k}.txt"
        pid = fork_main(argv(path), log)
        time.sleep(rng.uniform(0.3, 1.0) * duration)
        os.kill(pid, signal.SIGKILL)
        wait_child(pid)
        printed = _printed(log)
        if not path.exists() and not journal_dir(path).exists():
            assert not printed
            continue
        rep = recover(path)
        if rep.action == "no-calibration":
            assert not printed
            continue
        assert validate_session(path) == []
        s = read_session(path)
        by_name = {t.name: t for t in s.trials}
        for name, crc in printed:
            t = by_name[name]
            assert t.completed and crc == ref[name]
            assert f"{zlib.crc32(t.force_N.astype('<f8').tobytes()):08x}" == crc
        for t in s.trials:
            assert t.extra_attrs["controller"] in ("relay", "twin", "baseline")
            assert "target_json" in t.extra_attrs
            if not t.completed:
                assert t.abort_reason == PARTIAL_ABORT_REASON
        # issue 36: the killed tracking session resumes to completion, its completed
        # trials kept bit for bit, the recorded controller and targets reused
        kept = {t.name: t.force_N.copy() for t in s.trials if t.completed}
        assert main(["run", "--backend", "sim", "--resume", str(path), "--quiet"]) == 0
        assert validate_session(path) == []
        s = read_session(path)
        done = {t.extra_attrs["schedule_index"] for t in s.trials if t.completed}
        assert done == {0, 1, 2}
        for t in s.trials:
            if t.name in kept:
                assert np.array_equal(t.force_N, kept[t.name])
        assert [json.loads(t.extra_attrs["target_json"])["name"] for t in s.trials
                if t.completed and t.extra_attrs["controller"] != "relay"] == ["target"] * 2
        resumed += 1
        hit += bool(printed)
    assert hit >= 1 and resumed >= 1
