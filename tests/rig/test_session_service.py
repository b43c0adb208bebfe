"""A resume continues the same session on the same rig (issue 26, 2): every mismatch is
refused in one line naming it, before any device; the rest follows the rig's pacing."""

from __future__ import annotations

import pytest

from nmsid.cli import main
from nmsid.protocols.config import config_from_dict
from nmsid.protocols.session_file import read_session
from nmsid.rig.engine import Engine, EngineObserver, TripPolicy
from nmsid.rig.session_service import ResumeMismatch, RigRequest, prepare_rig, stored_session

SHORT = """
participant = "C01"
[protocol]
sE_levels = [0.4, 0.8]
repeats = 1
steady_s = 0.5
chirp_s = 1.0
rest_s = 0.4
[calibration]
hold_s = 0.3
baseline_s = 0.2
"""

HW = """
[rig]
fake = true
fake_speed = 10.0
[stimulator]
ceiling_ext_mA = 16.0
ceiling_flex_mA = 16.0
[acquisition]
kind = "caio"
[sensor]
sync_channel = 6
[sensor.channels]
Fx = 0
[sensor.rated]
Fx = 500.0
[sensor.rated_output_V]
Fx = 1.0
[sensor.offset_V]
Fx = 1.5
"""


@pytest.fixture
def sim_session(tmp_path):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT, encoding="utf-8")
    out = tmp_path / "s.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--sim-seed", "9", "--no-identify", "--quiet"]) == 0
    return out


def _one_line_exit_2(capsys, argv, *words):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


def test_recorded_at_the_start(sim_session):
    attrs = read_session(sim_session, load_data=False).attrs
    assert attrs["rig_backend"] == "sim" and int(attrs["sim_seed"]) == 9
    assert float(attrs["configured_rest_s"]) == 0.4     # the fast clock ran it at 0 s


def test_a_sim_session_does_not_resume_on_hardware(sim_session, tmp_path, capsys):
    hw = tmp_path / "hw.toml"
    hw.write_text(HW, encoding="utf-8")
    _one_line_exit_2(capsys, ["run", "--backend", "hw", "--hw-config", str(hw), "--resume",
                              str(sim_session)], "started on --backend sim")


def test_another_sim_seed_is_refused(sim_session, capsys):
    _one_line_exit_2(capsys, ["run", "--backend", "sim", "--resume", str(sim_session),
                              "--sim-seed", "5"], "seed 9, not --sim-seed 5")


def _hw_session(tmp_path, *, stop_after_first=True):
    hw = tmp_path / "hw.toml"
    hw.write_text(HW, encoding="utf-8")
    cfg = config_from_dict({
        "participant": "H01", "seed": 2, "interlock": {"stall_timeout_s": 2.0},
        "protocol": {"sE_levels": [0.5, 0.9, 0.7], "repeats": 1, "steady_s": 0.3,
                     "chirp_s": 0.5, "rest_s": 0.3},
        "calibration": {"manual": {"Iemin_mA": 2.5, "Iemax_mA": 7.0, "Ifmin_mA": 2.5,
                                   "Ifmax_mA": 7.0}}})
    path = tmp_path / "h.h5"
    rig = prepare_rig(RigRequest(backend="hw", session_path=path, hw_config=hw), cfg)
    box = {}

    class StopAfterFirst(EngineObserver):
        def on_trial_finished(self, index, trial):
            box["engine"].commands.abort("operator stop")

    try:
        engine = Engine(rig.config, rig.devices, path, observer=StopAfterFirst(),
                        trip_policy=TripPolicy.END_SESSION, extra_attrs=rig.extra_attrs)
        box["engine"] = engine
        engine.run()
    finally:
        rig.devices.close()
    return path, hw


def test_hardware_resume_checks_the_file_and_rests_as_configured(tmp_path, capsys,
                                                                  monkeypatch):
    path, hw = _hw_session(tmp_path)
    attrs, backend = stored_session(path)
    assert attrs["rig_backend"] == "hw" and len(attrs["hw_config_sha256"]) == 64
    assert attrs["hw_config_toml"] == HW and backend.startswith("hw:")
    # another hardware file: refused, naming the setting that differs
    other = tmp_path / "hw2.toml"
    other.write_text(HW.replace("Fx = 500.0", "Fx = 250.0"), encoding="utf-8")
    _one_line_exit_2(capsys, ["run", "--backend", "hw", "--hw-config", str(other),
                              "--resume", str(path)], "sensor.rated.Fx: 500.0 then, 250.0 now")
    _one_line_exit_2(capsys, ["run", "--backend", "sim", "--resume", str(path)],
                     "started on --backend hw")
    # the same file: resumes, resting 0.3 s between trials on the rig's clock
    rests = []
    real = Engine._sleep_checking

    def spy(self, duration_s):
        rests.append(duration_s)
        return real(self, duration_s)
    monkeypatch.setattr(Engine, "_sleep_checking", spy)
    assert main(["run", "--backend", "hw", "--hw-config", str(hw), "--resume", str(path),
                 "--no-identify", "--quiet"]) == 0, capsys.readouterr()
    assert 0.3 in rests
    assert read_session(path, load_data=False).backend.startswith("hw:")


def test_service_refuses_before_building_devices(tmp_path, monkeypatch):
    import nmsid.rig.session_service as svc
    monkeypatch.setattr(svc, "make_sim_rig", lambda *a, **k: pytest.fail("devices built"))
    cfg = config_from_dict({"participant": "X"})
    with pytest.raises(ResumeMismatch):
        prepare_rig(RigRequest(backend="sim", session_path=tmp_path / "x.h5", resume=True,
                               sim_seed=3, stored={"rig_backend": "sim", "sim_seed": 4}), cfg)
    with pytest.raises(ResumeMismatch):
        prepare_rig(RigRequest(backend="sim", session_path=tmp_path / "x.h5", resume=True,
                               stored={}, stored_backend="hw: MCS STG4002 + ..."), cfg)


def test_a_hardware_file_with_crlf_line_ends_is_the_same_rig(tmp_path):
    """Windows and git's autocrlf turn LF into CRLF: the resume check must not call that
    another hardware file."""
    from nmsid.rig.session_service import hw_fingerprint  # noqa: PLC0415
    lf, crlf = tmp_path / "lf.toml", tmp_path / "crlf.toml"
    lf.write_bytes(b"[rig]\nfake = true\n")
    crlf.write_bytes(b"[rig]\r\nfake = true\r\n")
    assert hw_fingerprint(lf) == hw_fingerprint(crlf)
    other = tmp_path / "other.toml"
    other.write_bytes(b"[rig]\nfake = false\n")
    assert hw_fingerprint(other)[0] != hw_fingerprint(lf)[0]


def test_a_hardware_file_without_backend_hw_is_refused_not_simulated(tmp_path, capsys):
    """Issue 36: ``--hw-config`` alone used to run a simulated session silently."""
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT, encoding="utf-8")
    hw = tmp_path / "hw.toml"
    hw.write_text(HW, encoding="utf-8")
    out = tmp_path / "x.h5"
    _one_line_exit_2(capsys, ["run", "--config", str(cfg), "--hw-config", str(hw), "--out",
                              str(out), "--no-identify"], "applies to --backend hw",
                     str(hw))
    assert not out.exists()


def test_the_hardware_files_rate_must_equal_the_protocols(tmp_path, capsys):
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT, encoding="utf-8")
    hw = tmp_path / "hw.toml"
    hw.write_text(HW.replace('kind = "caio"', 'kind = "caio"\nfs_Hz = 1000.0'),
                  encoding="utf-8")
    out = tmp_path / "x.h5"
    _one_line_exit_2(capsys, ["run", "--backend", "hw", "--config", str(cfg), "--hw-config",
                              str(hw), "--out", str(out), "--no-identify"],
                     "acquisition.fs_Hz = 1000", "fs_Hz = 2000", "must be equal")
    assert not out.exists()
