"""A weakened interlock needs --allow-weakened-safety; a confirmed one is recorded."""

from __future__ import annotations

from nmsid.cli import main
from nmsid.protocols.session_file import read_session

WEAK = """
participant = "C02"
[protocol]
sE_levels = [0.5]
repeats = 1
steady_s = 0.5
chirp_s = 1.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
rest_s = 0.2
[interlock]
trip_on_overrun = false
"""


def test_refused_without_confirmation_then_recorded(tmp_path, capsys):
    cfg = tmp_path / "weak.toml"
    cfg.write_text(WEAK)
    out = tmp_path / "s.h5"
    args = ["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
            "--no-identify", "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "interlock.trip_on_overrun" in err
    assert "--allow-weakened-safety" in err and not out.exists()
    assert main(args + ["--allow-weakened-safety"]) == 0
    s = read_session(out)
    assert s.config["interlock"]["confirm_weakened_safety"] is True
    weak = [e.detail for e in s.events if e.kind == "weakened_safety"]
    assert weak == ["confirmed: interlock.trip_on_overrun = false (that interlock rule "
                    "never trips)"]
