"""LSL outlets of a session (issue 43), read back by an independent pylsl inlet.

LSL stays on this machine: ``LSLAPICFG`` names a file with ``ResolveScope = machine`` and
IPv6 off before pylsl is first imported (here, and by the session-wide fixture in
tests/conftest.py), so no test sends LSL's default multicast or broadcast.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest

from nmsid.rig.lsl import MACHINE_ONLY_CFG, LslObserver, machine_only_config

if "LSLAPICFG" not in os.environ:          # before pylsl is imported (liblsl reads it once)
    machine_only_config(Path(tempfile.mkdtemp(prefix="nmsid-lsl-")))
pylsl = pytest.importorskip("pylsl")

from nmsid.cli import main  # noqa: E402
from nmsid.protocols.schedule import PlannedTrial  # noqa: E402
from nmsid.protocols.session_file import Event, read_session, validate_session  # noqa: E402
from nmsid.rig.observer import EngineObserver  # noqa: E402


def test_lsl_is_configured_for_this_machine_only():
    text = Path(os.environ["LSLAPICFG"]).read_text(encoding="utf-8")
    assert "ResolveScope = machine" in text and "IPv6 = disable" in text
    assert MACHINE_ONLY_CFG in text


def _inlet(source_id: str):
    found = pylsl.resolve_byprop("source_id", source_id, 1, 10.0)
    assert found, f"no LSL stream {source_id} on this machine"
    inlet = pylsl.StreamInlet(found[0], max_buflen=30)
    inlet.open_stream(10.0)
    return inlet, found[0]


def _pull(inlet, n, *, timeout_s=10.0):
    got, stamps = [], []
    deadline = pylsl.local_clock() + timeout_s
    while len(got) < n and pylsl.local_clock() < deadline:
        chunk, ts = inlet.pull_chunk(timeout=0.2)
        got += chunk
        stamps += ts
    return got, stamps


class _Record(EngineObserver):
    def __init__(self):
        self.calls = []

    def on_chunk(self, index, *rest):
        self.calls.append(("chunk", index))

    def on_trial_finished(self, index, trial):
        self.calls.append(("finished", index))


class _Trial:
    name, sE, status, abort_reason, n_samples = "trial_003", 0.7, "completed", "", 300
    rE = np.full(300, 0.5)


def test_round_trip_force_currents_and_markers():
    inner = _Record()
    obs = LslObserver(inner, 1000.0, name="nmsidtest", participant="LSL01")
    force, info = _inlet("nmsidtest-LSL01-force")
    stim, _ = _inlet("nmsidtest-LSL01-stimulation")
    markers, _ = _inlet("nmsidtest-LSL01-markers")
    assert info.type() == "Force" and info.nominal_srate() == 1000.0
    ch = force.info(10.0).desc().child("channels").child("channel")
    assert ch.child_value("label") == "force" and ch.child_value("unit") == "N"
    obs.on_trial_started(3, PlannedTrial(index=3, sE=0.7, repeat=0))
    f = np.arange(300, dtype=float)
    for lo in range(0, 300, 100):
        obs.on_chunk(3, lo, f[lo:lo + 100], np.full(100, 0.5), np.full(100, 6.0),
                     np.full(100, 2.5))
    obs.on_event(Event("2026-11-28T18:00:00Z", "interlock_trip", "estop: switch pressed"))
    obs.on_trial_finished(3, _Trial())
    samples, ts = _pull(force, 300)
    assert np.allclose(np.ravel(samples), f)
    assert np.allclose(np.diff(ts), 1e-3, atol=1e-6)          # stamped from one onset
    currents, _ = _pull(stim, 300)
    assert np.allclose(np.asarray(currents)[0], [6.0, 2.5, 0.5])
    marks, mts = _pull(markers, 3)
    events = [json.loads(m[0]) for m in marks]
    assert [e["event"] for e in events] == ["trial_start", "interlock_trip", "trial_end"]
    assert events[0] == {"event": "trial_start", "trial": 3, "sE": 0.7, "detail": ""}
    assert "estop" in events[1]["detail"]
    assert events[2]["rE_mean"] == 0.5 and events[2]["status"] == "completed"
    assert abs(mts[0] - ts[0]) < 1e-6          # the marker stamps the trial's first sample
    assert abs(mts[2] - (ts[0] + 0.3)) < 1e-6
    assert inner.calls == [("chunk", 3)] * 3 + [("finished", 3)]


def test_a_failing_outlet_never_reaches_the_session(caplog):
    inner = _Record()
    obs = LslObserver(inner, 1000.0, name="nmsidfail", participant="LSL02")

    def broken(*a, **kw):
        raise OSError("network gone")
    obs.force.push_chunk = broken
    obs.on_trial_started(0, PlannedTrial(index=0, sE=0.5, repeat=0))
    for lo in range(0, 300, 100):                # nothing raises; the session sees all
        obs.on_chunk(0, lo, np.zeros(100), np.zeros(100), np.zeros(100), np.zeros(100))
    obs.on_trial_finished(0, _Trial())
    assert inner.calls == [("chunk", 0)] * 3 + [("finished", 0)]
    assert "network gone" in obs.failed
    assert sum("LSL output switched off" in r.message for r in caplog.records) == 1


def test_nmsid_run_with_lsl_publishes_each_trial_start(tmp_path, monkeypatch, capsys):
    from nmsid.cli import run_command
    from nmsid.rig import lsl
    seen: dict = {}

    def with_inlet(inner, fs_Hz, participant):
        obs = lsl.lsl_observer(inner, fs_Hz, participant)
        seen["inlet"], _ = _inlet(f"nmsid-{participant}-markers")   # before the engine runs
        return obs
    monkeypatch.setattr(run_command, "lsl_observer", with_inlet)
    cfg = tmp_path / "p.toml"
    cfg.write_text('participant = "LSL03"\n[protocol]\nsE_levels = [0.4, 0.8]\nrepeats = 1\n'
                   'steady_s = 0.5\nchirp_s = 1.0\n[calibration]\nhold_s = 0.3\n'
                   'baseline_s = 0.2\n', encoding="utf-8")
    out = tmp_path / "s.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--no-identify", "--quiet", "--lsl"]) == 0, capsys.readouterr()
    assert validate_session(out) == [] and len(read_session(out).trials) == 2
    marks, _ = _pull(seen["inlet"], 100, timeout_s=3.0)
    decoded = [json.loads(m[0]) for m in marks]
    events = [e["event"] for e in decoded]
    assert all(re.fullmatch(r"trial t00[12] \(sE 0\.[48] repeat 1, attempt 1\)", e["detail"])
               for e in decoded if e["event"] == "trial_start")
    assert events.count("trial_start") == 2 and events.count("trial_end") == 2
    assert events[-1] == "session_finished"


def test_a_simulated_emg_stream_is_recorded_into_the_session_with_its_clock_offset(
        tmp_path, capsys):
    import threading

    import h5py
    info = pylsl.StreamInfo("SimEMG", "EMG", 2, 500.0, pylsl.cf_float32, "simemg-test-1")
    outlet = pylsl.StreamOutlet(info)
    stop = threading.Event()
    pushed = {"n": 0}

    def emg():                                # 500 Hz in chunks of 10, real time
        k = 0
        while not stop.is_set():
            outlet.push_chunk([[float(k + i), -float(k + i)] for i in range(10)])
            k += 10
            pushed["n"] = k
            stop.wait(0.02)
    t = threading.Thread(target=emg, daemon=True)
    t.start()
    cfg = tmp_path / "p.toml"
    cfg.write_text('participant = "LSL04"\n[protocol]\nsE_levels = [0.4]\nrepeats = 1\n'
                   'steady_s = 0.5\nchirp_s = 1.0\n[calibration]\nhold_s = 0.3\n'
                   'baseline_s = 0.2\n', encoding="utf-8")
    out = tmp_path / "s.h5"
    try:
        assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                     "--no-identify", "--quiet", "--lsl", "--lsl-record", "EMG"]) == 0, \
            capsys.readouterr()
    finally:
        stop.set()
        t.join(2.0)
    assert validate_session(out) == []        # the contract's items untouched
    with h5py.File(out, "r") as f:
        (run,) = f["lsl"].values()
        assert set(run) == {"SimEMG"}         # nmsid's own outlets are not re-recorded
        s = run["SimEMG"]
        x = s["time_series"][()]
        assert s.attrs["type"] == "EMG" and s.attrs["nominal_srate"] == 500.0
        assert x.shape[1] == 2 and len(x) >= 10 and np.all(x[:, 1] == -x[:, 0])
        assert np.all(np.diff(x[:, 0]) == 1)          # nothing lost between chunks
        assert len(s["time_stamps"]) == len(x)
        assert np.isfinite(s.attrs["clock_offset_s"]) and abs(s.attrs["clock_offset_s"]) < 0.1
        onsets = json.loads(run.attrs["trial_onsets_lsl_json"])
        assert list(onsets) == ["0"]


def test_the_protocol_files_lsl_table_publishes_as_the_flag_does(tmp_path, monkeypatch,
                                                                  capsys):
    # one definition: [lsl] publish = true in the protocol file is --lsl; the stored
    # configuration records it
    from nmsid.cli import run_command
    from nmsid.protocols.config import config_from_json
    from nmsid.rig import lsl
    seen: dict = {}

    def with_inlet(inner, fs_Hz, participant):
        obs = lsl.lsl_observer(inner, fs_Hz, participant)
        seen["inlet"], _ = _inlet(f"nmsid-{participant}-markers")
        return obs
    monkeypatch.setattr(run_command, "lsl_observer", with_inlet)
    cfg = tmp_path / "p.toml"
    cfg.write_text('participant = "LSL05"\n[protocol]\nsE_levels = [0.4]\nrepeats = 1\n'
                   'steady_s = 0.5\nchirp_s = 1.0\n[calibration]\nhold_s = 0.3\n'
                   'baseline_s = 0.2\n[lsl]\npublish = true\n', encoding="utf-8")
    out = tmp_path / "s.h5"
    assert main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
                 "--no-identify", "--quiet"]) == 0, capsys.readouterr()
    marks, _ = _pull(seen["inlet"], 100, timeout_s=3.0)
    assert [json.loads(m[0])["event"] for m in marks].count("trial_start") == 1
    stored = config_from_json(read_session(out).config_json)
    assert stored.lsl.publish is True and stored.lsl.record == ()


@pytest.mark.parametrize("table, key", [('publish = "yes"', "lsl.publish"),
                                        ('record = "EMG"', "lsl.record"),
                                        ('record = ["EMG", ""]', "lsl.record[1]"),
                                        ("outlets = true", "lsl.outlets")])
def test_a_bad_lsl_setting_is_one_line_naming_the_file_and_key(tmp_path, capsys, table,
                                                               key):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(f'participant = "LSL06"\n[lsl]\n{table}\n', encoding="utf-8")
    out = tmp_path / "s.h5"
    rc = main(["run", "--backend", "sim", "--config", str(cfg), "--out", str(out),
               "--no-identify", "--quiet", "--lsl"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert str(cfg) in err[0] and f"setting {key} = " in err[0], err[0]
    assert not out.exists()


def test_the_command_line_adds_to_the_files_lsl_settings():
    from nmsid.protocols.config import config_from_dict
    c = config_from_dict({"lsl": {"record": ["EMG"]}}).lsl
    assert c.with_command_line(False, None) is c
    assert c.with_command_line(True, None).publish and \
        c.with_command_line(True, None).record == ("EMG",)
    assert c.with_command_line(False, ["MoCap"]).record == ("MoCap",)
