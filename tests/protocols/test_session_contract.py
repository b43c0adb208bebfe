"""One definition of the session record: files written by plain h5py (not nmsid's writer)
at the edges of ``shared/spec/session-file-v1.md`` are read when the contract allows them
(implausible values are warnings), and every record the reader refuses, the writer refuses
(a hypothesis property over calibration and trial records)."""

import logging

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmsid.protocols.session_file import (
    Calibration,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    validate_session,
)

N = 200
CAL = {"Iemin_mA": 2.0, "Iemax_mA": 9.5, "Ifmin_mA": 1.5, "Ifmax_mA": 8.0, "Fmin_N": 0.5,
       "Fmax_N": 5.0}
TRIAL = {"sE": 0.5, "repeat": 1, "status": "completed", "abort_reason": "",
         "fs_Hz": 2000.0, "steady_s": 0.05, "chirp_s": 0.05, "chirp_f0_Hz": 1.0,
         "chirp_f1_Hz": 10.0, "carrier_Hz": 1000.0, "started_utc": "2026-11-22T01:30:00Z"}
DATA = {"rE": 0.5, "I_ext_mA": 3.0, "I_flex_mA": 2.0, "force_N": 1.0}


def _plain(path, cal=None, trial=None, data=None):
    """A session file written with h5py alone, as another lab's software would."""
    cal = {**CAL, **(cal or {})}
    trial = {**TRIAL, **(trial or {})}
    data = {**DATA, **(data or {})}
    s = h5py.string_dtype("utf-8")
    with h5py.File(path, "w") as f:
        for k, v in (("format", "nmsid-session"), ("participant", "X01"),
                     ("created_utc", "2026-11-22T01:30:00Z"), ("software", "otherlab 2.1")):
            f.attrs.create(k, v, dtype=s)
        f.attrs["format_version"] = np.int64(1)
        g = f.create_group("calibration")
        for k, v in cal.items():
            g.attrs[k] = v
        t = f.create_group("trials").create_group("t001")
        for k, v in trial.items():
            if isinstance(v, str):
                t.attrs.create(k, v, dtype=s)
            else:
                t.attrs[k] = v
        for k, v in data.items():
            t.create_dataset(k, data=np.full(N, v, dtype=np.float64))
    return path


@pytest.mark.parametrize("cal, trial, data, warned", [
    ({"Iemax_mA": 16.0176}, {}, {}, "Iemax_mA = 16.0176 is above"),       # issue 29's file
    ({"Iemax_mA": 130.0, "Ifmax_mA": 120.0}, {}, {"I_ext_mA": 100.0},    # a RehaStim2
     "Iemax_mA = 130 is above"),
    ({}, {"sE": 1.5}, {}, "sE = 1.5 is above 1"),                           # Eq. 4: Ie + If
    ({}, {}, {"force_N": 2500.0}, "beyond 1000 N"),
    ({"Fmin_N": -0.5}, {}, {}, "Fmin_N = -0.5 is outside"),
    ({}, {"chirp_f1_Hz": 1500.0}, {}, "above fs_Hz / 2"),
    ({}, {"fs_Hz": 5e6}, {}, "fs_Hz = 5e+06 is above"),
    ({}, {"abort_reason": "pain\nstopped", "status": "aborted"}, {}, "non-printable"),
])
def test_what_the_contract_allows_is_read_with_a_warning(tmp_path, caplog, cal, trial, data,
                                                          warned):
    path = _plain(tmp_path / "other.h5", cal, trial, data)
    warnings: list[str] = []
    assert validate_session(path, warnings=warnings) == []
    assert any(warned in w for w in warnings), warnings
    with caplog.at_level(logging.WARNING):
        s = read_session(path)
    assert len(s.trials) == 1 and s.trials[0].n_samples == N
    assert any(warned in w for w in s.warnings)
    assert any(warned in r.getMessage() for r in caplog.records)


def test_edges_the_contract_sets_are_accepted_exactly(tmp_path):
    # Iemin_mA = 0 (>= 0), Iemax just above it, sE tiny but > 0, rE exactly 0 and 1,
    # lengths 0, a 0 Hz chirp start, currents 0: all allowed, no warning
    path = _plain(tmp_path / "edge.h5", {"Iemin_mA": 0.0, "Iemax_mA": 1e-9},
                  {"sE": 1e-9, "steady_s": 0.0, "chirp_f0_Hz": 0.0, "repeat": np.int8(7)},
                  {"I_flex_mA": 0.0})
    with h5py.File(path, "a") as f:
        f["trials/t001/rE"][:2] = [0.0, 1.0]
    warnings: list[str] = []
    assert validate_session(path, warnings=warnings) == [] and warnings == []
    assert read_session(path).trials[0].repeat == 7


@pytest.mark.parametrize("cal, trial, data, refused", [
    ({"Iemin_mA": -0.1}, {}, {}, "Iemax_mA > Iemin_mA >= 0"),
    ({"Ifmax_mA": 1.5}, {}, {}, "Ifmax_mA > Ifmin_mA >= 0"),
    ({"Fmax_N": 0.5}, {}, {}, "Fmax_N > Fmin_N"),
    ({}, {"repeat": 0}, {}, "repeat = 0 is not valid"),
    ({}, {"repeat": 1.0}, {}, "repeat = 1.0 is not valid"),
    ({}, {"status": "done"}, {}, "status 'done' is not"),
    ({}, {"sE": 0.0}, {}, "sE = 0 is not valid"),
    ({}, {"fs_Hz": 0.0}, {}, "fs_Hz = 0 is not valid"),
    ({}, {}, {"rE": 1.5}, "outside [0, 1]"),
    ({}, {}, {"I_ext_mA": -1.0}, "below 0"),
    ({}, {}, {"force_N": np.inf}, "infinite"),
])
def test_what_the_contract_forbids_is_refused_by_reader_and_writer(tmp_path, cal, trial, data,
                                                                    refused):
    path = _plain(tmp_path / "bad.h5", cal, trial, data)
    assert any(refused in p for p in validate_session(path))
    with pytest.raises(SessionFileError, match=refused.replace("[", r"\[").replace("(", r"\(")):
        read_session(path)
    with pytest.raises(SessionFileError, match="refusing"):
        _write_with_nmsid(tmp_path / "w.h5", cal, trial, data)


def _write_with_nmsid(path, cal, trial, data):
    w = SessionWriter.create(path, participant="X01")
    c = {**CAL, **cal}
    w.write_calibration(Calibration(**c))
    t = {**TRIAL, **trial}
    d = {k: np.full(N, v, dtype=np.float64) for k, v in {**DATA, **data}.items()}
    w.append_trial(Trial(**t, **d))


# -- the property: every record the reader refuses, the writer refuses ----------------------
EDGY = st.sampled_from([-1.0, -1e-12, 0.0, 1e-9, 0.5, 1.0, 1.0000001, 1.5, 16.0176, 130.0,
                        2500.0, 1e6, 5e6, 1e300, np.nan, np.inf, -np.inf])
CAL_FIELDS = st.dictionaries(st.sampled_from(sorted(CAL)), EDGY, max_size=3)
TRIAL_FIELDS = st.fixed_dictionaries({}, optional={
    "sE": EDGY, "fs_Hz": EDGY, "steady_s": EDGY, "chirp_s": EDGY, "chirp_f0_Hz": EDGY,
    "chirp_f1_Hz": EDGY, "carrier_Hz": EDGY,
    "repeat": st.sampled_from([-1, 0, 1, 2, 1.0, 1.5]),
    "status": st.sampled_from(["completed", "aborted", "done", ""]),
})
DATA_FIELDS = st.dictionaries(st.sampled_from(sorted(DATA)), EDGY, max_size=2)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(cal=CAL_FIELDS, trial=TRIAL_FIELDS, data=DATA_FIELDS)
def test_the_writer_refuses_every_record_the_reader_refuses(tmp_path_factory, cal, trial, data):
    if trial.get("status") == "aborted":
        trial["abort_reason"] = "stopped"
    d = tmp_path_factory.mktemp("prop")
    try:
        read_session(_plain(d / "plain.h5", cal, trial, data))
        reader_refuses = False
    except SessionFileError:
        reader_refuses = True
    try:
        _write_with_nmsid(d / "nmsid.h5", cal, trial, data)
        writer_refuses = False
    except SessionFileError:
        writer_refuses = True
    assert writer_refuses == reader_refuses, (cal, trial, data)
    if not writer_refuses:  # what the writer wrote, the reader reads
        assert len(read_session(d / "nmsid.h5").trials) == 1


def test_validate_calls_a_130_mA_file_valid_and_identify_analyses_it(tmp_path, capsys):
    """Issue 29: every contract-valid file is analysed; the implausible is a warning."""
    from nmsid.cli import main
    from nmsid.testing.sessions import write_synthetic_session
    path = tmp_path / "rehastim.h5"
    write_synthetic_session(path, seed=5, sE_levels=(0.4, 0.7), repeats=2, steady_s=1.0,
                            chirp_s=4.0)
    with h5py.File(path, "a") as f:        # another stimulator's calibration (RehaStim2)
        f["calibration"].attrs["Iemax_mA"] = 130.0
    assert main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "valid nmsid session file" in out and "1 warning(s)" in out
    assert "warning: /calibration attribute Iemax_mA = 130 is above" in out
    assert main(["identify", str(path), "--out", str(tmp_path / "out"), "--no-figures"]) == 0
    assert (tmp_path / "out" / "parameters.csv").exists()
