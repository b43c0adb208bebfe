"""``nmsid probe`` checks its own flags before it touches any device (issue 26): a dry-run
current or dummy load out of range is one line, exit 2, and no device was probed."""

from __future__ import annotations

import pytest

from nmsid.cli import main


@pytest.mark.parametrize("flags, says", [
    (["--dry-run-mA", "50"], "dry-run amplitude 50 mA"),
    (["--load-ohm", "5"], "dummy load 5 Ohm"),
    (["--dry-run-mA", "5", "--load-ohm", "10000"], "above the A/D's"),
])
def test_dry_run_flags_are_refused_before_any_device(write_hw_config, tmp_path, capsys,
                                                     monkeypatch, flags, says):
    from nmsid.cli import probe_command

    def never(*a, **kw):
        raise AssertionError("a device was probed before the flags were checked")

    monkeypatch.setattr(probe_command, "prepare", never)
    path = write_hw_config(tmp_path / "hw.toml", kind="caio", fs_Hz=2000.0, monitor=7)
    assert main(["probe", "--hw-config", str(path), "--dry-run", *flags]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], captured.err
    assert "stimulator:" not in captured.out


def test_samples_above_the_bound_are_refused_not_capped(write_hw_config, tmp_path, capsys):
    path = write_hw_config(tmp_path / "hw.toml", kind="caio", fs_Hz=2000.0)
    with pytest.raises(SystemExit) as exc:
        main(["probe", "--hw-config", str(path), "--samples", "1000000000"])
    assert exc.value.code == 2 and "[1, 10000]" in capsys.readouterr().err
