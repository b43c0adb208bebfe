"""One session service for the CLI and the GUI: resuming a simulated session of the CLI
in the GUI rebuilds the same participant (the recorded seed, not 0)."""

from __future__ import annotations

from pathlib import Path

import pytest

from nmsid.cli import main
from nmsid.rig.gui.session_controller import SessionController, load_session_config
from nmsid.rig.gui.setup_panel import Backend, SessionRequest
from nmsid.rig.session_service import ResumeMismatch

SHORT = """
participant = "G01"
[protocol]
sE_levels = [0.4, 0.8]
repeats = 1
steady_s = 0.5
chirp_s = 1.0
[calibration]
hold_s = 0.3
baseline_s = 0.2
"""


def test_gui_resume_of_a_cli_session_rebuilds_the_same_participant(tmp_path):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT, encoding="utf-8")
    out = tmp_path / "s.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--sim-seed", "9", "--no-identify", "--quiet"]) == 0
    request = SessionRequest(participant="G01", backend=Backend.SIM, output_path=out,
                             resume=True, seed=None)
    config = load_session_config(request)
    rig = SessionController.prepare(request, config)
    try:
        assert rig.sim_seed == 9
        assert rig.devices.participant.seed == 9
    finally:
        rig.devices.close()
    hw = tmp_path / "hw.toml"
    hw.write_text("[rig]\nfake = true\n", encoding="utf-8")
    on_hw = SessionRequest(participant="G01", backend=Backend.HW, output_path=out,
                           hw_config_path=hw, resume=True)
    with pytest.raises(ResumeMismatch, match="started on --backend sim"):
        SessionController.prepare(on_hw, config)
    assert Path(out).exists()
