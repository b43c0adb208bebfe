"""The session-file module against shared/spec/session-file-v1.md."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nmsid.protocols.session_file import (
    Calibration,
    Event,
    SessionExistsError,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    validate_session,
)


def make_trial(n=200, sE=0.5, repeat=1, status="completed", reason="", **kw):
    rng = np.random.default_rng(n + repeat)
    return Trial(sE=sE, repeat=repeat, fs_Hz=2000.0, rE=np.linspace(0, 1, n),
                 I_ext_mA=np.full(n, 4.0), I_flex_mA=np.full(n, 3.0),
                 force_N=rng.normal(size=n), status=status, abort_reason=reason,
                 started_utc="2026-11-22T01:30:00Z", **kw)


@pytest.fixture
def session_path(tmp_path):
    path = tmp_path / "P01.h5"
    w = SessionWriter.create(path, participant="P01", config_json='{"repeats": 3}', seed=7,
                             backend="sim")
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0,
                                    ramps={"ext_I_mA": np.arange(5.0)}))
    w.append_trial(make_trial(sE=0.3, repeat=1, wrench=np.zeros((200, 6)), sync=np.ones(200)))
    w.append_trial(make_trial(n=50, sE=0.35, repeat=1, status="aborted", reason="E-stop"))
    w.append_events([Event("2026-11-22T01:31:00Z", "estop", "operator pressed E-stop")])
    return path


def test_round_trip_keeps_every_item(session_path):
    s = read_session(session_path)
    assert s.participant == "P01" and s.seed == 7 and s.backend == "sim"
    assert s.config == {"repeats": 3}
    assert s.calibration.Iemax_mA == 9.0 and s.calibration.Ifmin_mA == 1.5
    np.testing.assert_array_equal(s.calibration.ramps["ext_I_mA"], np.arange(5.0))
    assert [t.name for t in s.trials] == ["t001", "t002"]
    t1, t2 = s.trials
    np.testing.assert_array_equal(t1.force_N, make_trial(sE=0.3).force_N)
    assert t1.wrench.shape == (200, 6) and t1.sync.shape == (200,)
    assert t2.status == "aborted" and t2.abort_reason == "E-stop" and t2.n_samples == 50
    assert [t.name for t in s.completed_trials()] == ["t001"]
    assert s.events[0].kind == "estop"
    assert validate_session(session_path) == []


def test_strings_are_utf8_variable_length(session_path):
    with h5py.File(session_path, "r") as f:
        dt = f.attrs.get_id("participant").dtype
        assert h5py.check_string_dtype(dt).encoding == "utf-8"
        assert h5py.check_string_dtype(dt).length is None
        assert f["trials/t001/rE"].dtype == np.float64


def test_never_overwrites(session_path):
    before = session_path.read_bytes()
    with pytest.raises(SessionExistsError, match="never overwrites"):
        SessionWriter.create(session_path, participant="P02")
    assert session_path.read_bytes() == before


def test_bad_participant_code_is_refused(tmp_path):
    with pytest.raises(ValueError, match="participant code 'Jane Doe'"):
        SessionWriter.create(tmp_path / "x.h5", participant="Jane Doe")


def test_bad_calibration_is_refused(tmp_path):
    w = SessionWriter.create(tmp_path / "x.h5", participant="P1")
    with pytest.raises(ValueError, match="Iemax_mA > Iemin_mA"):
        w.write_calibration(Calibration(5.0, 4.0, 1.0, 2.0))


def test_trial_with_mismatched_lengths_is_refused(session_path):
    t = make_trial()
    t.rE = t.rE[:-1]
    with pytest.raises(ValueError, match="rE must be 1-D with 200 samples"):
        SessionWriter.open(session_path).append_trial(t)


def _break(path, action):
    with h5py.File(path, "a") as f:
        action(f)


BREAKAGES = {
    "no format": (lambda f: f.attrs.__delitem__("format"),
                  "missing required root attribute 'format'"),
    "wrong format": (lambda f: f.attrs.__setitem__("format", "other"),
                     "root attribute format is 'other'"),
    "wrong version": (lambda f: f.attrs.__setitem__("format_version", 2),
                      "format_version is 2"),
    "no participant": (lambda f: f.attrs.__delitem__("participant"),
                       "missing required root attribute 'participant'"),
    "a name as participant": (lambda f: f.attrs.__setitem__("participant", "Jane Doe"),
                              "participant 'Jane Doe' is not"),
    "bad created_utc": (lambda f: f.attrs.__setitem__("created_utc", "yesterday"),
                        "created_utc 'yesterday' is not ISO 8601"),
    "no calibration": (lambda f: f.__delitem__("calibration"),
                       "missing required group /calibration"),
    "no Fmax": (lambda f: f["calibration"].attrs.__delitem__("Fmax_N"),
                "missing required attribute /calibration/Fmax_N"),
    "Iemin above Iemax": (lambda f: f["calibration"].attrs.__setitem__("Iemin_mA", 20.0),
                          "Iemax_mA > Iemin_mA >= 0"),
    "no trials": (lambda f: f.__delitem__("trials"), "missing required group /trials"),
    "no sE": (lambda f: f["trials/t001"].attrs.__delitem__("sE"),
              "missing required attribute /trials/t001/sE"),
    "no repeat": (lambda f: f["trials/t001"].attrs.__delitem__("repeat"),
                  "missing required attribute /trials/t001/repeat"),
    "no force": (lambda f: f["trials/t001"].__delitem__("force_N"),
                 "missing required dataset /trials/t001/force_N"),
    "short rE": (lambda f: (f["trials/t001"].__delitem__("rE"),
                            f["trials/t001"].create_dataset("rE", data=np.zeros(10))),
                 "datasets differ in length"),
    "2-D force": (lambda f: (f["trials/t001"].__delitem__("force_N"),
                             f["trials/t001"].create_dataset("force_N", data=np.zeros((200, 2)))),
                  "/trials/t001/force_N must be a 1-D dataset"),
    "bad status": (lambda f: f["trials/t001"].attrs.__setitem__("status", "done"),
                   "status 'done' is not"),
    "aborted without reason": (lambda f: f["trials/t002"].attrs.__setitem__("abort_reason", ""),
                               "aborted but abort_reason is empty"),
    "sE out of range": (lambda f: f["trials/t001"].attrs.__setitem__("sE", -0.5),
                        "sE = -0.5 is not valid (valid: > 0"),
    "gap in trial names": (lambda f: f["trials"].move("t002", "t005"),
                           "numbered t001, t002, ... without gaps"),
    "wrench shape": (lambda f: (f["trials/t001"].__delitem__("wrench"),
                                f["trials/t001"].create_dataset("wrench", data=np.zeros((200, 3)))),
                     "wrench must have shape (200, 6)"),
}


@pytest.mark.parametrize("kind", sorted(BREAKAGES))
def test_validate_names_each_violation(session_path, kind):
    action, message = BREAKAGES[kind]
    _break(session_path, action)
    problems = validate_session(session_path)
    assert any(message in p for p in problems), problems


@pytest.mark.parametrize("kind", ["no format", "no calibration", "no force", "no sE", "no trials"])
def test_reader_error_names_file_and_item(session_path, kind):
    action, message = BREAKAGES[kind]
    _break(session_path, action)
    with pytest.raises(SessionFileError) as err:
        read_session(session_path)
    assert str(session_path) in str(err.value) and message in str(err.value)


def test_not_hdf5_and_missing_file(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"this is not HDF5")
    with pytest.raises(SessionFileError, match="junk.h5: cannot be opened as HDF5"):
        read_session(junk)
    with pytest.raises(SessionFileError, match="nothere.h5: no such file"):
        read_session(tmp_path / "nothere.h5")


def test_reader_ignores_unknown_items(session_path):
    _break(session_path, lambda f: (f.create_group("extra_lab_stuff"),
                                    f["trials/t001"].attrs.__setitem__("lab_note", "hi"),
                                    f["trials/t001"].create_dataset("emg", data=np.zeros(3))))
    s = read_session(session_path)
    assert s.trials[0].extra_attrs["lab_note"] == "hi"
    assert validate_session(session_path) == []


def test_reading_only_some_datasets(session_path):
    s = read_session(session_path, datasets=("rE", "force_N"))
    t = s.trials[0]
    assert t.n_samples == 200 and len(t.rE) == 200
    assert t.I_ext_mA.size == 0 and t.wrench is None and t.sync is None
    listing = read_session(session_path, load_data=False)
    assert listing.trials[1].status == "aborted" and listing.trials[0].force_N.size == 0
