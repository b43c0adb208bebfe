"""``nmsid validate`` prints every violation and exits non-zero on a broken file."""

from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np

from nmsid.cli import main
from nmsid.protocols.session_file import Calibration, SessionWriter, Trial


def _good(path):
    w = SessionWriter.create(path, participant="P01")
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0))
    n = 20
    w.append_trial(Trial(sE=0.3, repeat=1, fs_Hz=2000.0, rE=np.zeros(n), I_ext_mA=np.zeros(n),
                         I_flex_mA=np.zeros(n), force_N=np.zeros(n)))
    return path


def test_valid_file(tmp_path, capsys):
    path = _good(tmp_path / "ok.h5")
    assert main(["validate", str(path)]) == 0
    assert "valid nmsid session file" in capsys.readouterr().out


def test_every_violation_is_printed(tmp_path, capsys):
    path = _good(tmp_path / "bad.h5")
    with h5py.File(path, "a") as f:
        del f.attrs["software"]
        del f["trials/t001/I_flex_mA"]
        f["calibration"].attrs["Ifmin_mA"] = -1.0
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr().out
    assert "INVALID (3 problem(s))" in out
    assert "'software'" in out and "/trials/t001/I_flex_mA" in out and "Ifmin_mA" in out


def test_console_script_gives_one_line_not_a_traceback(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_text("nope")
    proc = subprocess.run([sys.executable, "-m", "nmsid.cli", "validate", str(junk)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["nmsid: error: 1 of 1 file(s) invalid (see above)"]
    assert "Traceback" not in proc.stdout + proc.stderr
    assert "cannot be opened as HDF5" in proc.stdout
