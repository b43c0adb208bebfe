"""Crash-safe logging: the journal, recovery of damaged / incomplete files, never
overwriting, the partial trial."""

import os

import numpy as np
import pytest

from nmsid.protocols.session_file import (
    Calibration,
    SessionExistsError,
    SessionFileError,
    SessionWriter,
    Trial,
    read_session,
    validate_session,
)
from nmsid.rig.session_log import PARTIAL_ABORT_REASON, SessionLog, journal_dir, recover


def _trial(i, n=500, status="completed"):
    rng = np.random.default_rng(i)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rng.random(n),
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 status=status, abort_reason="" if status == "completed" else "test",
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i})


def _session(tmp_path, n_trials=3):
    path = tmp_path / "P01.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.event("start", "hello")
    log.write_calibration(Calibration(1, 9, 1.5, 10, ramps={"ext_I_mA": np.arange(3.0)}))
    trials = [_trial(i) for i in range(n_trials)]
    for t in trials:
        log.end_trial(t)
    return path, log, trials


def _same(a, b):
    return all(np.array_equal(getattr(a, k), getattr(b, k))
               for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N")) and a.sE == b.sE


def test_clean_finish_removes_the_journal(tmp_path):
    path, log, trials = _session(tmp_path)
    assert journal_dir(path).is_dir()
    assert log.finish()
    assert not journal_dir(path).exists()
    s = read_session(path)
    assert len(s.trials) == 3 and all(_same(a, b) for a, b in zip(s.trials, trials, strict=True))
    assert [e.kind for e in s.events] == ["start"]
    assert s.seed == 3 and s.attrs["schedule_json"] == "[]"


def test_never_overwrites(tmp_path):
    path, log, _ = _session(tmp_path, 1)
    log.close()
    with pytest.raises(SessionExistsError):
        SessionLog.create(path, participant="P01", config_json="{}", seed=1, backend="x",
                          schedule_json="[]")
    other = tmp_path / "Q.h5"
    journal_dir(other).mkdir()
    with pytest.raises(SessionExistsError):
        SessionLog.create(other, participant="P01", config_json="{}", seed=1, backend="x",
                          schedule_json="[]")


def test_damaged_file_rebuilt_and_kept_aside(tmp_path):
    path, log, trials = _session(tmp_path)
    log.close()
    good = path.read_bytes()
    with open(path, "r+b") as fh:  # scribble over the superblock and truncate
        fh.write(b"\0" * 64)
        fh.truncate(len(good) // 2)
    assert validate_session(path)
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.damaged_kept_at
    assert os.path.getsize(rep.damaged_kept_at) == len(good) // 2
    s = read_session(path)
    assert validate_session(path) == [] and len(s.trials) == 3
    assert all(_same(a, b) for a, b in zip(s.trials, trials, strict=True))
    assert s.calibration.Iemax_mA == 9 and np.array_equal(s.calibration.ramps["ext_I_mA"],
                                                         np.arange(3.0))
    assert [e.kind for e in s.events] == ["start"]
    # a second recovery finds nothing to do and keeps the good file
    assert recover(path).action == "none"


@pytest.mark.parametrize("fraction", np.linspace(0.05, 0.995, 24))
def test_file_cut_anywhere_is_reported_not_raised_and_rebuilt(tmp_path, fraction):
    """A kill can leave the HDF5 file short of what its headers point at (h5py then
    raises KeyError 'len not positive after adjustment for EOA' deep inside a read).
    Validation reports it, reading raises our error naming the file, recovery rebuilds."""
    path, log, trials = _session(tmp_path, 4)
    log.close()
    good = path.read_bytes()
    with open(path, "r+b") as fh:
        fh.truncate(int(len(good) * fraction))
    problems = validate_session(path)          # never raises
    assert isinstance(problems, list)
    try:
        read_session(path)
    except SessionFileError as exc:
        assert str(path) in str(exc)
    rep = recover(path)
    s = read_session(path)
    assert validate_session(path) == [] and len(s.trials) == 4
    assert all(_same(a, b) for a, b in zip(s.trials, trials, strict=True))
    assert rep.action in ("rebuilt", "appended", "none")


def test_stale_end_of_file_address_is_reported_and_rebuilt(tmp_path):
    """A kill while a trial is appended can leave the superblock's end-of-allocation from
    before the append while the new trial's group is already linked: h5py then raises
    KeyError ('len not positive after adjustment for EOA') on opening that trial."""
    path, log, trials = _session(tmp_path, 2)
    before = path.read_bytes()
    trials.append(_trial(2))
    log.end_trial(trials[-1])
    log.close()
    after = path.read_bytes()
    path.write_bytes(before[:96] + after[96:])    # the old superblock, the new body
    problems = validate_session(path)
    assert len(problems) == 1 and "damaged" in problems[0] and "nmsid recover" in problems[0]
    with pytest.raises(SessionFileError, match="nmsid recover"):
        read_session(path)
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.damaged_kept_at
    s = read_session(path)
    assert validate_session(path) == [] and len(s.trials) == 3
    assert all(_same(a, b) for a, b in zip(s.trials, trials, strict=True))


def test_trial_journaled_but_not_in_file_is_appended(tmp_path):
    path, log, trials = _session(tmp_path, 2)
    log.close()
    # simulate a kill between the journal rename and the HDF5 append: build the file anew
    # with only the first trial
    os.replace(path, tmp_path / "full.h5")
    w = SessionWriter.create(path, participant="P01", seed=3)
    w.write_calibration(Calibration(1, 9, 1.5, 10))
    w.append_trial(_trial(0))
    rep = recover(path)
    assert rep.action == "appended" and rep.n_appended == 1
    s = read_session(path)
    assert len(s.trials) == 2 and _same(s.trials[1], trials[1])


def test_partial_trial_becomes_aborted(tmp_path):
    path, log, trials = _session(tmp_path, 1)
    meta = _trial(7, n=0)
    log.begin_trial(meta)
    f = np.arange(10.0)
    log.append_chunk(force_N=f[:6], rE=f[:6] / 10, I_ext_mA=f[:6], I_flex_mA=f[:6])
    log.append_chunk(force_N=f[6:], rE=f[6:] / 10, I_ext_mA=f[6:], I_flex_mA=f[6:])
    log._close_partial()
    # a torn last row (a kill in the middle of a write) is ignored
    with open(journal_dir(path) / "partial.f64", "ab") as fh:
        fh.write(b"\1" * 12)
    log.close()
    rep = recover(path)
    assert rep.partial_recovered and rep.partial_samples == 10
    s = read_session(path)
    assert validate_session(path) == []
    last = s.trials[-1]
    assert last.status == "aborted" and last.abort_reason == PARTIAL_ABORT_REASON
    assert np.array_equal(last.force_N, f) and last.extra_attrs["schedule_index"] == 7
    assert not (journal_dir(path) / "partial.json").exists()
    recovered = [e.detail for e in s.events if e.kind == "recovered"]
    assert recovered and recovered[0].startswith(f"trial {last.name} kept as aborted")
    # idempotent
    rep2 = recover(path)
    assert rep2.action == "none" and len(read_session(path).trials) == 2


def test_killed_before_calibration_has_nothing_to_recover(tmp_path):
    path = tmp_path / "P.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=1, backend="x",
                            schedule_json="[]")
    log.event("start")
    log.close()
    assert recover(path).action == "no-calibration"
    assert not path.exists()


def test_no_journal_damaged_file_is_an_error(tmp_path):
    path = tmp_path / "x.h5"
    path.write_bytes(b"not hdf5")
    with pytest.raises(SessionFileError, match="no journal"):
        recover(path)


def test_resume_rebuilds_a_journal_from_a_clean_file(tmp_path):
    path, log, trials = _session(tmp_path, 2)
    log.finish()
    log2, rep = SessionLog.resume(path)
    assert rep is None and len(log2.trials) == 2
    log2.end_trial(_trial(5))
    log2.close()
    # damage it now: the rebuilt journal holds all three
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    recover(path)
    s = read_session(path)
    assert len(s.trials) == 3 and _same(s.trials[0], trials[0])


def test_torn_event_line_is_ignored(tmp_path):
    path, log, _ = _session(tmp_path, 1)
    log.close()
    with open(journal_dir(path) / "events.jsonl", "a") as fh:
        fh.write('{"utc": "2026-11-22T01:00:00Z", "ki')
    os.remove(path)
    assert recover(path).action == "rebuilt"
    assert [e.kind for e in read_session(path).events] == ["start"]
