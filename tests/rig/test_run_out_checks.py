"""`nmsid run` refuses a bad --out before any device is touched (no journal left)."""

import pytest

import nmsid.cli.run_command as run_command
from nmsid.cli import main
from nmsid.rig.session_log import journal_dir
from nmsid.testing.platforms import WINE_SYMLINK


@pytest.fixture
def no_devices(monkeypatch):
    touched = []
    monkeypatch.setattr(run_command, "prepare_rig",
                        lambda *a: touched.append(a) or pytest.fail("devices touched"))
    return touched


@pytest.mark.wine_gap(WINE_SYMLINK)
def test_dangling_symlink_out_is_refused_before_devices(tmp_path, no_devices, capsys):
    out = tmp_path / "s.h5"
    try:
        out.symlink_to(tmp_path / "gone" / "s.h5")
    except OSError as exc:  # Windows: WinError 1314 without the privilege
        pytest.skip("Windows: creating a symbolic link needs Developer Mode or an "
                    f"administrator ({exc})")
    assert main(["run", "--backend", "sim", "--out", str(out), "--no-identify"]) == 2
    err = capsys.readouterr().err
    assert "dangling symbolic link" in err and len(err.strip().splitlines()) == 1
    assert not no_devices and not journal_dir(out).exists()


def test_existing_out_or_journal_is_refused_before_devices(tmp_path, no_devices, capsys):
    out = tmp_path / "s.h5"
    out.write_text("mine")
    assert main(["run", "--backend", "sim", "--out", str(out), "--no-identify"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "mine"
    other = tmp_path / "t.h5"
    journal_dir(other).mkdir()
    assert main(["run", "--backend", "sim", "--out", str(other), "--no-identify"]) == 2
    assert "--resume" in capsys.readouterr().err and not no_devices
