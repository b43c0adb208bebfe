"""Property-based fuzzing of the command line: every bad value ends in exit 2 and exactly
one line on stderr, quickly.

In-process (``nmsid.cli.main``) for speed; hypothesis draws the bad values (non-finite,
negative, huge, not a number, garbage paths) for every sub-command's numeric and path
options. Each example has a deadline of a few seconds, so a value that hangs fails. A few
real subprocesses check the same from outside.
"""

import contextlib
import io
import math
import os
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.cli import main
from nmsid.testing.platforms import WINE_SYMLINK

ROOT = Path(__file__).resolve().parents[1]
FUZZ = settings(max_examples=25, deadline=5000, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


def _run(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, err.getvalue()


def _refused(argv):
    code, err = _run(argv)
    lines = err.strip().splitlines()
    assert code == 2, (argv, code, err)
    assert len(lines) == 1 and "Traceback" not in err, (argv, err)
    return lines[0]


def _fmt(v) -> str:
    return repr(v) if isinstance(v, float) and math.isfinite(v) else str(v)


def _outside(lo, hi, *, lo_open=False):
    """Floats not in [lo, hi] (or (lo, hi]), plus nan and +-inf."""
    below = st.floats(max_value=lo, exclude_max=not lo_open, allow_nan=False)
    above = st.floats(min_value=hi, exclude_min=True, allow_nan=False)
    return st.one_of(below, above, st.sampled_from([math.nan, math.inf, -math.inf]))


GARBAGE = st.sampled_from(["", "abc", "1e309x", "0x", "--", "nan%", "1,5", "\x1b[2J",
                           "9" * 400])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    twin = d / "twin.json"
    twin.write_text('{"format": "nmsid-twin", "format_version": 1, "participant": "P", '
                    '"sE_range": [0.3, 1.0], "parameters": {'
                    '"Kp": {"model": "constant", "coefficients": [5.0]}, '
                    '"wn_rad_s": {"model": "constant", "coefficients": [30.0]}, '
                    '"zeta": {"model": "constant", "coefficients": [0.7]}}}')
    session = d / "s.h5"
    with h5py.File(session, "w") as f:
        f.attrs["format"] = "nmsid-session"
    (d / "dangling").symlink_to(d / "nowhere" / "x")
    return {"twin": twin, "session": session, "dir": d, "dangling": d / "dangling"}


@FUZZ
@given(option=st.sampled_from(["--fs-Hz", "--steady-s", "--chirp-s", "--sE", "--f0-Hz",
                               "--f1-Hz"]), data=st.data())
def test_twin_simulate_numbers(files, option, data):
    bounds = {"--fs-Hz": (1, 1e5, False), "--steady-s": (0, 3600, False),
              "--chirp-s": (0, 3600, True), "--sE": (0, 10, True),
              "--f0-Hz": (0, 1000, True), "--f1-Hz": (0, 1000, True)}[option]
    v = data.draw(st.one_of(_outside(*bounds[:2], lo_open=bounds[2]), GARBAGE))
    line = _refused(["twin", "simulate", str(files["twin"]), "--rE-chirp", "--sE", "0.5",
                     option, _fmt(v), "--out", str(files["dir"] / "f.csv")])
    assert option in line or "argument" in line
    assert not (files["dir"] / "f.csv").exists()


@FUZZ
@given(option=st.sampled_from(["--iqr-k", "--lowpass-Hz", "--butter-order",
                               "--savgol-window", "--savgol-order", "--window-start-s",
                               "--window-end-s", "--fit-fs-Hz"]), data=st.data())
def test_identify_settings(files, option, data):
    ints = option in ("--butter-order", "--savgol-window", "--savgol-order")
    bad = (st.one_of(st.integers(max_value=0), st.integers(min_value=10 ** 6), GARBAGE)
           if ints else st.one_of(st.floats(max_value=-1e-9, allow_nan=False),
                                  st.sampled_from([math.nan, math.inf, -math.inf]), GARBAGE))
    v = data.draw(bad)
    line = _refused(["identify", str(files["session"]), "--out", str(files["dir"] / "o"),
                     option, _fmt(v)])
    # refused for the value (the session here is a stub: any other refusal would hide it)
    assert option in line or option[2:].replace("-", "_") in line, line
    assert not (files["dir"] / "o").exists()


@FUZZ
@given(data=st.data())
def test_gap_design_study_run_numbers(files, data):
    d = files["dir"]
    case = data.draw(st.sampled_from([
        (["gap", str(files["session"]), "--out", str(d / "g"), "--ic-margin"], (0, 1000)),
        (["gap", str(files["session"]), "--out", str(d / "g"), "--min-shrink-pct"],
         (0, 100)),
        (["design", "--population", "--out", str(d / "d"), "--noise-N"], (0, 10)),
        (["design", "--population", "--out", str(d / "d"), "--tolerance"], (0, 1)),
        (["design", "--population", "--out", str(d / "d"), "--min-steady-s"], (0, 60)),
    ]))
    argv, (lo, hi) = case
    v = data.draw(st.one_of(_outside(lo, hi, lo_open=argv[-1] == "--noise-N"), GARBAGE))
    assert argv[-1] in _refused([*argv, _fmt(v)])
    ints = data.draw(st.sampled_from([
        (["design", "--population", "--out", str(d / "d"), "--n-prior"], (1, 1000)),
        (["design", "--population", "--out", str(d / "d"), "--validate"], (0, 1000)),
        (["study", str(d), "--out", str(d / "st"), "--workers"], (0, 256)),
        (["run", "--backend", "sim", "--out", str(d / "r.h5"), "--seed"], (0, 2 ** 63 - 1)),
        (["run", "--backend", "sim", "--out", str(d / "r.h5"), "--sim-seed"],
         (0, 2 ** 63 - 1)),
    ]))
    argv, (lo, hi) = ints
    n = data.draw(st.one_of(st.integers(max_value=lo - 1), st.integers(min_value=hi + 1),
                            GARBAGE))
    assert argv[-1] in _refused([*argv, str(n)])
    assert not any((d / x).exists() for x in ("g", "d", "st", "r.h5"))


@FUZZ
@pytest.mark.wine_gap(WINE_SYMLINK)   # its first bad path is a dangling link
@given(data=st.data())
def test_paths(files, data):
    d = files["dir"]
    bad_path = data.draw(st.sampled_from([
        str(files["dangling"]), str(files["session"]), str(d / "missing" / "x.toml"),
        str(d), "\x1b[2Jname"]))
    cmd = data.draw(st.sampled_from([
        ["twin", "simulate", str(files["twin"]), "--rE-chirp", "--sE", "0.5", "--out",
         "{p}"],
        ["twin", "simulate", "{p}", "--rE-chirp", "--sE", "0.5", "--out", str(d / "f.csv")],
        ["run", "--backend", "sim", "--config", "{p}", "--out", str(d / "r.h5")],
        ["run", "--backend", "sim", "--out", "{p}"],
        ["identify", str(files["session"]), "--out", "{p}"],
        ["gap", str(files["session"]), "--out", "{p}"],
        ["export", "nwb", str(files["session"]), "--out", "{p}"],
        ["recover", "{p}"],
    ]))
    argv = [a.replace("{p}", bad_path) for a in cmd]
    if argv[:2] == ["run", "--backend"] and bad_path == "\x1b[2Jname" and "--out" in argv \
            and argv[-1] == bad_path:
        return  # a valid new file name: not a bad value
    if argv[0] in ("identify", "gap") and bad_path == "\x1b[2Jname":
        return  # a valid new folder name
    if argv[0] == "twin" and argv[-1] == "\x1b[2Jname":
        return  # a valid new file name
    line = _refused(argv)
    assert "\x1b" not in line


@pytest.mark.parametrize("link", [False, pytest.param(True, id="dangling-link", marks=(
    pytest.mark.wine_gap(WINE_SYMLINK)))])
def test_real_subprocesses_refuse_in_one_line(files, link):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    argvs = ([["run", "--out", str(files["dangling"])]] if link else
             [["twin", "simulate", str(files["twin"]), "--rE-chirp", "--sE", "0.5",
               "--fs-Hz", "1e12", "--out", str(files["dir"] / "f.csv")],
              ["run", "--seed", str(2 ** 63), "--out", str(files["dir"] / "r.h5")]])
    for argv in argvs:
        p = subprocess.run([sys.executable, "-m", "nmsid.cli", *argv], capture_output=True,
                           text=True, timeout=60, cwd=str(ROOT), env=env)
        assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, (argv, p.stderr)


# -- issue 26: every plain mistake in one line with exit 2 -----------------------------------
def _mistakes(files):
    d = files["dir"]
    long_name = str(d / ("a" * 216 + ".h5"))       # 219 bytes: the aside names would pass 255
    out = [
        ["validate", ""], ["validate", "."], ["validate", str(d)], ["recover", "."],
        ["recover", "/"], ["recover", ""], ["qc", "."], ["identify", "", "--out", str(d / "o")],
        ["run", "--backend", "sim", "--resume", "."],
        ["run", "--backend", "sim", "--out", long_name],
        ["run", "--backend", "sim", "--resume", long_name],
        ["recover", long_name],
        ["gui", "--out", long_name],
        ["design", "--population", "--seed", "-5", "--out", str(d / "d")],
        ["design", "--population", "--seed", str(2 ** 63), "--out", str(d / "d")],
        ["gui", "--seed", "-1"], ["gui", "--seed", str(2 ** 63)], ["gui", "--seed", "x"],
        ["probe", "--hw-config", str(d / "hw.toml"), "--samples", "1000000000"],
        ["probe", "--hw-config", str(d / "hw.toml"), "--samples", "0"],
        ["export", "nwb", str(files["session"]), "--out", str(d / "x.nwb"),
         "--subject-age", "notaduration"],
        ["export", "nwb", str(files["session"]), "--out", str(d / "x.nwb"),
         "--subject-age", "P30"],
        ["export", "nwb", str(files["session"]), "--out", str(d / "x.nwb"),
         "--experimenter", ""],
        ["export", "nwb", str(files["session"]), "--out", str(d / "x.nwb"),
         "--experimenter", "  "],
    ]
    if hasattr(os, "mkfifo"):  # POSIX: a FIFO is refused before anything reads (it waits)
        fifo = d / "fifo"
        if not fifo.exists():
            os.mkfifo(fifo)
        out += [["validate", str(fifo)], ["recover", str(fifo)], ["qc", str(fifo)],
                ["identify", str(fifo), "--out", str(d / "o")],
                ["run", "--backend", "sim", "--resume", str(fifo)]]
    if sys.platform != "win32":  # bytes that are not UTF-8 reach argv as surrogate escapes
        raw = os.fsdecode(str(d).encode() + b"/\xff\xfe.h5")
        out += [["validate", raw], ["identify", raw, "--out", str(d / "o")],
                ["gap", raw, "--out", str(d / "g")], ["qc", raw],
                ["export", "nwb", raw, "--out", str(d / "x.nwb")],
                ["export", "nwb", str(files["session"]), "--out", raw],
                ["run", "--backend", "sim", "--out", raw], ["study", raw, "--out", str(d / "s")],
                ["identify", str(files["session"]), "--out", raw]]
    return out


@settings(max_examples=40, deadline=5000, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_plain_mistakes_of_issue_26(files, data):
    argv = data.draw(st.sampled_from(_mistakes(files)))
    line = _refused(argv)
    assert "internal error" not in line and "\udcff" not in line, line
    assert not any((files["dir"] / x).exists() for x in ("o", "d", "g", "s", "x.nwb"))


@FUZZ
@given(rE=st.one_of(st.floats(max_value=-1e-12, allow_nan=False),
                    st.floats(min_value=1.0, exclude_min=True, allow_nan=False),
                    st.sampled_from([math.nan, 1e308, -1e308, math.inf, -math.inf])))
def test_twin_simulate_refuses_an_input_rE_outside_0_1(files, rE):
    d = files["dir"]
    csv = d / "in.csv"
    csv.write_text("rE,sE\n0.5,0.5\n" + f"{rE!r},0.5\n" + "0.5,0.5\n", encoding="utf-8")
    line = _refused(["twin", "simulate", str(files["twin"]), "--input", str(csv),
                     "--out", str(d / "f.csv")])
    assert "'rE' row 3" in line and "[0, 1]" in line, line
    assert not (d / "f.csv").exists()


def test_study_of_a_folder_with_a_name_that_is_not_utf8(tmp_path):
    if sys.platform == "win32":
        pytest.skip("Windows file names are always Unicode")
    folder = tmp_path / "sessions"
    folder.mkdir()
    (folder / os.fsdecode(b"\xff.h5")).write_bytes(b"")
    line = _refused(["study", str(folder), "--out", str(tmp_path / "st")])
    assert "not UTF-8" in line and "\\xff" in line
