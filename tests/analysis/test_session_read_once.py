"""A command reads a session file once and passes the decoded session on (identify with
its quality control, qc, gap with its quality control, pre-processing and report)."""

from __future__ import annotations

import pytest

from nmsid.cli import main
from nmsid.testing.sessions import write_gap_session


@pytest.fixture(scope="module")
def short_session(tmp_path_factory):
    return write_gap_session(tmp_path_factory.mktemp("once") / "s.h5", levels=(0.3, 0.6),
                             repeats=2, steady_s=3.0, chirp_s=6.0, seed=3)


@pytest.mark.parametrize("argv", [["identify", "--no-figures"], ["qc"],
                                  ["gap", "--no-figures", "--no-pairs"]],
                         ids=["identify", "qc", "gap"])
def test_one_read_per_command(short_session, session_reads, tmp_path, capsys, argv):
    command, options = argv[0], argv[1:]
    out = ["--out", str(tmp_path / "out")] if command != "qc" else []
    assert main([command, str(short_session), *out, *options]) == 0
    capsys.readouterr()
    assert session_reads(short_session) == 1


def test_gap_with_a_twin_still_reads_once(short_session, session_reads, tmp_path, capsys):
    """The twin run as the simulation under test takes rE and sE from the same read."""
    assert main(["gap", str(short_session), "--out", str(tmp_path / "a"), "--no-figures",
                 "--no-pairs"]) == 0
    before = session_reads(short_session)
    assert main(["gap", str(short_session), "--out", str(tmp_path / "b"), "--no-figures",
                 "--no-pairs", "--twin", str(tmp_path / "a" / "twin.json")]) == 0
    capsys.readouterr()
    assert session_reads(short_session) - before == 1
