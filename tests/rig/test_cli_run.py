"""``nmsid run`` / ``nmsid recover`` in-process on the simulated rig (fast clock)."""

import sys

import numpy as np
import pytest

from nmsid.cli import main
from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.session_log import journal_dir

SHORT = """
participant = "C01"
[protocol]
sE_levels = [0.4, 0.8]
repeats = 2
steady_s = 0.5
chirp_s = 1.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
"""


@pytest.fixture
def short_toml(tmp_path):
    p = tmp_path / "short.toml"
    p.write_text(SHORT)
    return p


def test_run_writes_a_valid_file_and_prints_progress(tmp_path, short_toml, capsys):
    out = tmp_path / "s.h5"
    code = main(["run", "--backend", "sim", "--config", str(short_toml), "--out", str(out),
                 "--seed", "3", "--no-identify"])
    text = capsys.readouterr().out
    assert code == 0
    assert validate_session(out) == [] and not journal_dir(out).exists()
    s = read_session(out)
    assert s.participant == "C01" and s.seed == 3 and len(s.trials) == 4
    assert s.config["protocol"]["rest_s"] == 0.0  # fast clock: no rest
    for t in s.trials:
        assert f"{t.name} completed" in text
    assert "4 completed, 0 aborted, 0 not run (schedule complete)" in text


def test_outdir_names_and_never_overwrites(tmp_path, short_toml, capsys):
    args = ["run", "--backend", "sim", "--config", str(short_toml), "--outdir",
            str(tmp_path / "sessions"), "--participant", "P9", "--no-identify", "--quiet"]
    assert main(args) == 0
    assert main(args) == 0  # same second: a new name, the first file untouched
    files = sorted((tmp_path / "sessions").glob("P9-*.h5"))
    assert len(files) == 2 and all(validate_session(f) == [] for f in files)
    existing = files[0]
    before = existing.read_bytes()
    code = main(["run", "--backend", "sim", "--config", str(short_toml), "--out",
                 str(existing), "--no-identify"])
    assert code == 2 and "never overwrites" in capsys.readouterr().err
    assert existing.read_bytes() == before


def test_bad_config_refused_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[protocol]\nsE_levels = [0.5, 1.5]\n")
    code = main(["run", "--backend", "sim", "--config", str(bad), "--out",
                 str(tmp_path / "x.h5")])
    err = capsys.readouterr().err
    assert code == 2 and "bad.toml" in err and "protocol.sE_levels" in err
    assert err.count("\n") == 1 and not (tmp_path / "x.h5").exists()
    code = main(["run", "--backend", "sim", "--resume", str(tmp_path / "x.h5"), "--seed", "1"])
    assert code == 2 and "--resume" in capsys.readouterr().err
    code = main(["run", "--backend", "hw", "--out", str(tmp_path / "y.h5")])
    assert code == 2 and "--hw-config" in capsys.readouterr().err


def test_recover_command(tmp_path, short_toml, capsys):
    out = tmp_path / "s.h5"
    main(["run", "--backend", "sim", "--config", str(short_toml), "--out", str(out),
          "--no-identify", "--quiet"])
    capsys.readouterr()
    assert main(["recover", str(out)]) == 0
    assert "nothing to recover" in capsys.readouterr().out


def test_run_then_identify(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[protocol]\nsE_levels = [0.4, 0.6, 0.8]\nrepeats = 2\nsteady_s = 1.0\n'
                   'chirp_s = 4.0\n[calibration]\nmanual = {Iemin_mA = 2.0, Iemax_mA = 9.5, '
                   'Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n')
    out = tmp_path / "I.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    analysis = tmp_path / "I-analysis"
    assert (analysis / "parameters.csv").exists() and "3/3 levels identified" in text
    rows = (analysis / "parameters.csv").read_text().splitlines()
    assert len(rows) == 4
    assert np.isfinite(float(rows[1].split(",")[2]))
    # issue 39: a resume of the complete session runs no trial and names the analysis
    # instead of writing I-analysis-2, -3, ...
    assert main(["run", "--backend", "sim", "--resume", str(out), "--quiet"]) == 0
    assert f"already in {analysis}; not repeated" in capsys.readouterr().out
    assert not (tmp_path / "I-analysis-2").exists()


@pytest.mark.skipif(sys.platform == "win32", reason="Windows: Ctrl+C is a console event, "
                    "not a signal another process can send (send_signal(SIGINT) raises); "
                    "tests/test_windows_console_events.py runs it through the console API")
def test_ctrl_c_is_an_estop_and_leaves_a_valid_file(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    cfg = tmp_path / "c.toml"
    cfg.write_text('participant = "CC"\n[protocol]\nsE_levels = [0.5, 0.7]\nrepeats = 1\n'
                   'steady_s = 1.0\nchirp_s = 2.0\n[calibration]\nmanual = {Iemin_mA = 2.0, '
                   'Iemax_mA = 9.5, Ifmin_mA = 1.5, Ifmax_mA = 8.0}\n')
    out = tmp_path / "cc.h5"
    proc = subprocess.Popen(
        [sys.executable, "-m", "nmsid.cli", "run", "--backend", "sim", "--realtime", "--config",
         str(cfg), "--out", str(out), "--no-identify"], stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, cwd=str(Path(__file__).resolve().parents[2]),
        env=dict(os.environ, PYTHONUNBUFFERED="1"))
    stream = journal_dir(out) / "partial.f64"
    t0 = time.monotonic()
    # wait until the first trial has streamed a few chunks (real time), then press Ctrl+C
    while proc.poll() is None and time.monotonic() - t0 < 60 and not (
            # 11 float64 columns a row: rE, two currents, force, the 6-axis wrench, sync
            stream.exists() and stream.stat().st_size >= 8 * 11 * 400):
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    text = proc.communicate(timeout=60)[0].decode()
    assert proc.returncode == 130, text  # 128 + SIGINT
    assert "E-stop" in text and "--resume" in text
    assert validate_session(out) == [] and not journal_dir(out).exists()
    s = read_session(out)
    assert len(s.trials) == 1
    assert s.trials[0].abort_reason.startswith("estop: SIGINT received (Ctrl+C")
    assert 400 <= s.trials[0].n_samples < 6000
    assert any(e.kind == "interlock_trip" for e in s.events)


def test_resume_uses_the_stored_virtual_participant(tmp_path, short_toml, monkeypatch,
                                                    capsys):
    import nmsid.cli.run_command as cli_run

    out = tmp_path / "s.h5"
    assert main(["run", "--backend", "sim", "--config", str(short_toml), "--out", str(out),
                 "--sim-seed", "9", "--no-identify", "--quiet"]) == 0
    assert int(read_session(out, load_data=False).attrs["sim_seed"]) == 9
    seen = []
    real = cli_run.prepare_rig

    def spy(request, config):
        rig = real(request, config)
        seen.append(rig.sim_seed)
        return rig
    monkeypatch.setattr(cli_run, "prepare_rig", spy)
    assert main(["run", "--backend", "sim", "--resume", str(out), "--no-identify"]) == 0
    assert seen == [9]
    assert "4 completed, 0 aborted, 0 not run" in capsys.readouterr().out
    assert validate_session(out) == [] and not journal_dir(out).exists()
