"""NWB export: every sample comes back through pynwb; nwbinspector finds nothing critical."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nmsid.protocols.session_file import Calibration, Event, SessionWriter, Trial, read_session

pynwb = pytest.importorskip("pynwb")
pytest.importorskip("nwbinspector")

from nmsid.export.nwb import export_nwb, inspect_nwb, trial_start_times_s  # noqa: E402


def _session(path, rng, *, fs_Hz, n, wrench=True, events=True, gzip_level=4):
    w = SessionWriter.create(path, participant="P-07", created_utc="2026-03-01T09:00:00Z",
                             config_json=json.dumps({"fs_Hz": fs_Hz, "stim": {"mA": [1, 2]}}),
                             seed=11, backend="sim", gzip_level=gzip_level)
    w.write_calibration(Calibration(1.2, 8.5, 1.7, 9.9, 0.5, 5.0,
                                    ramps={"ext_I_mA": rng.uniform(0, 9, 50),
                                           "ext_force_N": rng.normal(0, 2, 50)}))
    trials = []
    for k, (sE, status) in enumerate([(0.3, "completed"), (0.6, "aborted"), (0.9, "completed")]):
        m = n if status == "completed" else n // 3
        t = Trial(sE=sE, repeat=1 + k % 2, fs_Hz=fs_Hz, rE=rng.uniform(0, 1, m),
                  I_ext_mA=rng.uniform(0, 10, m), I_flex_mA=rng.uniform(0, 10, m),
                  force_N=rng.normal(0, 3, m) * 10 ** rng.uniform(-3, 2),
                  status=status, abort_reason="E-stop pressed" if status == "aborted" else "",
                  started_utc=f"2026-03-01T09:0{k + 1}:00Z",
                  wrench=rng.normal(0, 1, (m, 6)) if wrench else None,
                  sync=(rng.integers(0, 2, m) * 5.0) if k == 0 else None)
        w.append_trial(t)
        trials.append(t)
    if events:
        w.append_events([Event("2026-03-01T09:02:03Z", "estop", "operator pressed E-stop"),
                         Event("2026-03-01T09:00:30Z", "note", "")])
    return trials


@pytest.mark.parametrize("fs_Hz,n,wrench,gzip_level", [(2000.0, 600, True, 4),
                                                       (500.0, 257, False, None),
                                                       (1000.0, 1000, True, 9)])
def test_round_trip_every_sample(tmp_path, fs_Hz, n, wrench, gzip_level):
    rng = np.random.default_rng(int(fs_Hz) + n)
    src = tmp_path / "s.h5"
    trials = _session(src, rng, fs_Hz=fs_Hz, n=n, wrench=wrench, gzip_level=gzip_level)
    out = export_nwb(src, tmp_path / "s.nwb")
    assert out.n_trials == 3
    session = read_session(src)
    starts = trial_start_times_s(session)
    with pynwb.NWBHDF5IO(str(out.path), "r") as io:
        nwb = io.read()
        assert nwb.subject.subject_id == "P-07"
        assert nwb.subject.species == "Homo sapiens"
        assert set(nwb.devices) == {"stimulator", "ad_converter", "force_sensor"}
        for t, t0 in zip(trials, starts, strict=True):
            rE = nwb.stimulus[f"rE_{t.name}"]
            np.testing.assert_array_equal(rE.data[:], t.rE)
            assert rE.rate == fs_Hz and rE.starting_time == pytest.approx(t0)
            for key, label in (("I_ext_mA", "I_ext"), ("I_flex_mA", "I_flex")):
                ts = nwb.stimulus[f"{label}_{t.name}"]
                np.testing.assert_array_equal(ts.data[:], getattr(t, key))
                assert ts.unit == "A" and ts.conversion == 1e-3
            f = nwb.acquisition[f"force_{t.name}"]
            np.testing.assert_array_equal(f.data[:], t.force_N)
            assert f.unit == "N"
            if wrench:
                np.testing.assert_array_equal(nwb.acquisition[f"wrench_force_{t.name}"].data[:],
                                              t.wrench[:, :3])
                np.testing.assert_array_equal(nwb.acquisition[f"wrench_moment_{t.name}"].data[:],
                                              t.wrench[:, 3:])
            else:
                assert f"wrench_force_{t.name}" not in nwb.acquisition
            if t.sync is not None:
                np.testing.assert_array_equal(nwb.acquisition[f"sync_{t.name}"].data[:], t.sync)
        tr = nwb.trials.to_dataframe()
        assert list(tr["trial_name"]) == ["t001", "t002", "t003"]
        np.testing.assert_allclose(tr["sE"], [0.3, 0.6, 0.9])
        assert list(tr["status"]) == ["completed", "aborted", "completed"]
        assert list(tr["abort_reason"]) == ["", "E-stop pressed", ""]
        np.testing.assert_allclose(tr["stop_time"] - tr["start_time"],
                                   [len(t.force_N) / fs_Hz for t in trials])
        assert (tr["start_time"].to_numpy()[1:] >= tr["stop_time"].to_numpy()[:-1]).all()
        ev = nwb.get_events_table("events").to_dataframe() if hasattr(
            nwb, "get_events_table") else None
        assert list(ev["kind"]) == ["note", "estop"]  # sorted by time
        np.testing.assert_allclose(ev["timestamp"], [30.0, 123.0])
        misc = nwb.processing["misc"]
        cal = misc["calibration"].to_dataframe().set_index("quantity")["value"]
        assert cal["Iemax_mA"] == 8.5 and cal["Ifmin_mA"] == 1.7
        meta = misc["session_metadata"].to_dataframe().set_index("key")["value"]
        assert meta["seed"] == "11" and json.loads(meta["config.stim.mA"]) == [1, 2]
        np.testing.assert_array_equal(
            misc["calibration_ext_I_mA"]["ext_I_mA"].data[:], session.calibration.ramps["ext_I_mA"])


def test_inspector_finds_nothing_critical_or_fixable(tmp_path):
    rng = np.random.default_rng(5)
    src = tmp_path / "s.h5"
    _session(src, rng, fs_Hz=1000.0, n=400)
    out = export_nwb(src, tmp_path / "s.nwb", experimenter=["Doe, Jane"], institution="Lab")
    findings = inspect_nwb(out.path)
    assert [(m.importance.name, m.check_function_name) for m in findings] == []


def test_inspector_without_optional_metadata_only_suggests(tmp_path):
    src = tmp_path / "s.h5"
    _session(src, np.random.default_rng(6), fs_Hz=1000.0, n=300, events=False)
    findings = inspect_nwb(export_nwb(src, tmp_path / "s.nwb").path)
    assert {m.check_function_name for m in findings} <= {"check_experimenter_exists",
                                                        "check_institution"}
    assert all(m.importance.name == "BEST_PRACTICE_SUGGESTION" for m in findings)


def test_never_overwrites(tmp_path):
    src = tmp_path / "s.h5"
    _session(src, np.random.default_rng(1), fs_Hz=1000.0, n=100)
    (tmp_path / "s.nwb").write_bytes(b"keep")
    with pytest.raises(FileExistsError, match="s.nwb"):
        export_nwb(src, tmp_path / "s.nwb")
    assert (tmp_path / "s.nwb").read_bytes() == b"keep"


def test_cli_export_and_bad_file(tmp_path, capsys):
    from nmsid.cli import main
    src = tmp_path / "s.h5"
    _session(src, np.random.default_rng(2), fs_Hz=1000.0, n=100)
    assert main(["export", "nwb", str(src), "--out", str(tmp_path / "o.nwb"), "--inspect"]) == 0
    assert "3 trial(s)" in capsys.readouterr().out
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    assert main(["export", "nwb", str(bad), "--out", str(tmp_path / "b.nwb")]) == 2
    err = capsys.readouterr().err
    assert "bad.h5" in err and err.count("\n") == 1


def test_cli_several_sessions_give_one_file_each_in_a_folder(tmp_path, capsys):
    """Issue 39: `export nwb sessions/P01-*.h5` refused more than one file."""
    from nmsid.cli import main
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    _session(a, np.random.default_rng(3), fs_Hz=1000.0, n=100)
    _session(b, np.random.default_rng(4), fs_Hz=1000.0, n=100)
    assert main(["export", "nwb", str(a), str(b), "--out", str(tmp_path / "o.nwb")]) == 2
    assert "give a folder" in capsys.readouterr().err
    assert not (tmp_path / "o.nwb").exists()
    assert main(["export", "nwb", str(a), str(b), "--out", str(tmp_path / "nwb")]) == 0
    out = capsys.readouterr().out
    assert out.count("3 trial(s)") == 2
    for name in ("a.nwb", "b.nwb"):
        with pynwb.NWBHDF5IO(str(tmp_path / "nwb" / name), "r") as io:
            assert len(io.read().trials) == 3
