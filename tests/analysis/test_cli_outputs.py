"""Commands never overwrite what the user did not ask to replace; bad values are refused
in one line (twin simulate bounds, identify's exit status and repeated files)."""

import json

import h5py
import pytest

from nmsid.analysis.twin import Curve, Twin
from nmsid.cli import main
from nmsid.cli.identify_command import EXIT_NOTHING_IDENTIFIED


@pytest.fixture
def twin_path(tmp_path):
    tw = Twin("P01", {"Kp": Curve("linear", [1.0, 8.0]), "wn_rad_s": Curve("constant", [30.0]),
                      "zeta": Curve("constant", [0.6])}, (0.3, 1.0))
    p = tmp_path / "twin.json"
    tw.save(p)
    return p


def _one_line(capsys):
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("fs", ["0", "-1", "1e8", "1e12", "inf", "nan"])
def test_twin_simulate_refuses_absurd_rates_in_one_line(tmp_path, twin_path, capsys, fs):
    out = tmp_path / "f.csv"
    assert main(["twin", "simulate", str(twin_path), "--sE", "0.5", "--rE-chirp",
                 "--fs-Hz", fs, "--out", str(out)]) == 2
    err = _one_line(capsys)
    assert "--fs-Hz" in err and "[1, 100000] Hz" in err and not out.exists()


def test_twin_simulate_bounds_its_length(tmp_path, twin_path, capsys):
    assert main(["twin", "simulate", str(twin_path), "--sE", "0.5", "--rE-chirp",
                 "--fs-Hz", "100000", "--chirp-s", "3000", "--out",
                 str(tmp_path / "f.csv")]) == 2
    assert "at most 5,000,000" in _one_line(capsys)


def test_twin_simulate_never_overwrites_a_session_even_with_force(tmp_path, twin_path,
                                                                  capsys):
    s = tmp_path / "s.h5"
    with h5py.File(s, "w") as f:
        f.attrs["format"] = "nmsid-session"
    before = s.read_bytes()
    for extra in ([], ["--force"]):
        assert main(["twin", "simulate", str(twin_path), "--sE", "0.5", "--rE-chirp",
                     "--out", str(s), *extra]) == 2
        assert "never overwrites a session file" in _one_line(capsys)
    assert s.read_bytes() == before
    csv = tmp_path / "f.csv"
    csv.write_text("mine")
    argv = ["twin", "simulate", str(twin_path), "--sE", "0.5", "--rE-chirp", "--chirp-s",
            "1", "--out", str(csv)]
    assert main(argv) == 2 and "give --force" in _one_line(capsys)
    assert csv.read_text() == "mine"
    assert main([*argv, "--force"]) == 0 and csv.read_text().startswith("t_s,rE,sE")


def test_twin_simulate_refuses_effects_it_cannot_simulate(tmp_path, twin_path, capsys):
    data = json.loads(twin_path.read_text())
    data["effects"] = [{"name": "dead_time", "params": {"L_s": 0.02}},
                       {"name": "baseline_drift", "params": {"amplitude_N": 0.2}}]
    twin_path.write_text(json.dumps(data))
    argv = ["twin", "simulate", str(twin_path), "--sE", "0.5", "--rE-chirp", "--chirp-s",
            "1", "--out", str(tmp_path / "f.csv")]
    assert main(argv) == 2
    assert "effect(s) baseline_drift cannot be simulated" in _one_line(capsys)
    assert main([*argv, "--without-effects"]) == 0
    data["effects"] = data["effects"][:1]          # a dead time alone is simulated
    twin_path.write_text(json.dumps(data))
    assert main([*argv[:-1], str(tmp_path / "g.csv")]) == 0


def test_identify_out_refused_then_forced_and_a_repeated_file_counts_once(
        small_session, tmp_path, capsys):
    path = small_session[0]
    out = tmp_path / "o"
    assert main(["identify", str(path), str(path), "--out", str(out), "--no-figures"]) == 0
    text = capsys.readouterr().out
    assert "same file as" in text and "1 session(s)" in text
    (out / "mine.txt").write_text("user's")
    assert main(["identify", str(path), "--out", str(out), "--no-figures"]) == 2
    assert "give --force" in _one_line(capsys) and (out / "mine.txt").exists()
    # issue 39: --force replaces only what nmsid wrote; the user's file stays
    assert main(["identify", str(path), "--out", str(out), "--no-figures", "--force"]) == 2
    assert "mine.txt, which nmsid did not write" in _one_line(capsys)
    assert (out / "mine.txt").read_text() == "user's"
    (out / "mine.txt").unlink()
    (out / "parameters.csv").write_text("old")
    assert main(["identify", str(path), "--out", str(out), "--no-figures", "--force"]) == 0
    assert (out / "parameters.csv").read_text() != "old"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".nmsid-tmp")]
    # an output folder holding a session file is never replaced
    assert main(["identify", str(path), "--out", str(path.parent), "--force"]) == 2
    assert "holds the session file" in _one_line(capsys)


def test_identify_exits_3_when_nothing_was_identified(small_session, tmp_path, capsys,
                                                      monkeypatch):
    import nmsid.analysis.run as run_mod
    real = run_mod.identify_session

    def no_fits(src, settings):
        res = real(src, settings)
        for lv in res.levels:
            lv.fit = None
        return res
    monkeypatch.setattr(run_mod, "identify_session", no_fits)
    code = main(["identify", str(small_session[0]), "--out", str(tmp_path / "o"),
                 "--no-figures"])
    assert code == EXIT_NOTHING_IDENTIFIED == 3
    assert "no sE level could be identified" in capsys.readouterr().err


def test_vv_shows_nmsid_debug_but_not_the_libraries(small_session, tmp_path):
    """Issue 39: -vv mostly added h5py's DEBUG lines; now only -vvv lets libraries log."""
    import re
    import subprocess
    import sys

    def debug_loggers(flag, out):
        err = subprocess.run([sys.executable, "-m", "nmsid", flag, "identify",
                              str(small_session[0]), "--out", str(tmp_path / out),
                              "--no-figures"], capture_output=True, text=True,
                             timeout=600).stderr
        return {m.group(1).split(".")[0] for m in re.finditer(r" DEBUG (\S+):", err)}

    assert "h5py" in debug_loggers("-vvv", "a")      # the libraries do log when asked
    assert debug_loggers("-vv", "b") <= {"nmsid"}
