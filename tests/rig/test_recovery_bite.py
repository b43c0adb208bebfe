"""Tests that bite (issue 29, 5) for recovery: what it says it did (a damaged file kept
aside, named in its summary), and what killed writers left beside a session is cleaned
by the next recovery. Behaviour only: files on disk and the report's words."""

from __future__ import annotations

import os

import numpy as np
import pytest

from nmsid.protocols.session_file import Calibration, Trial, read_session
from nmsid.rig.session_log import SessionLog, journal_dir, recover


def _trial(i, n=300):
    rng = np.random.default_rng(i)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rng.random(n),
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i})


def _killed_session(tmp_path, n_trials=2):
    path = tmp_path / "P01.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    for i in range(n_trials):
        log.end_trial(_trial(i))
    log.close()                       # a kill: the journal stays
    return path


def test_the_summary_names_the_damaged_file_kept_aside(tmp_path):
    path = _killed_session(tmp_path)
    with open(path, "r+b") as fh:     # scribble over the superblock
        fh.write(b"\0" * 64)
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.damaged_kept_at
    assert os.path.exists(rep.damaged_kept_at)
    assert f"the damaged file was kept as {rep.damaged_kept_at}" in rep.summary()
    assert "rebuilt from the journal; 2 trials in the file" in rep.summary()
    assert len(read_session(path).trials) == 2


def test_a_complete_file_is_said_to_be_complete(tmp_path):
    path = _killed_session(tmp_path)
    rep = recover(path)
    assert rep.action == "none"
    assert rep.summary() == f"{path}: complete (2 trials); nothing to recover"
    assert "kept as" not in rep.summary() and "kept as aborted" not in rep.summary()


def test_recovery_removes_what_killed_writers_left(tmp_path):
    path = _killed_session(tmp_path)
    jdir = journal_dir(path)
    left = [path.with_name(path.name + ".writing-4242"),
            path.with_name(path.name + ".recovering-4243"),
            jdir.with_name(jdir.name + ".done-4244"), jdir.with_name(jdir.name + ".tmp-4245"),
            jdir / "trial-0009.npz.tmp"]
    for p in left[:2] + left[4:]:
        p.write_bytes(b"half")
    for p in left[2:4]:
        p.mkdir()
        (p / "x").write_bytes(b"x")
    rep = recover(path)
    assert not any(os.path.lexists(p) for p in left), [p.name for p in left if p.exists()]
    assert rep.leftovers_removed == len(left)
    assert len(read_session(path).trials) == 2


def test_trial_digest_tells_trials_apart_sample_for_sample():
    from nmsid.rig.journal import trial_digest
    a, b = _trial(0), _trial(0)
    assert trial_digest(a) == trial_digest(b) != 0
    b.force_N = b.force_N.copy()
    b.force_N[7] += 1e-9
    assert trial_digest(a) != trial_digest(b)
    for k in ("rE", "I_ext_mA", "I_flex_mA"):
        c = _trial(0)
        setattr(c, k, getattr(c, k)[::-1].copy())
        assert trial_digest(c) != trial_digest(a), k


def test_stale_temps_are_found_for_a_path_given_as_text(tmp_path):
    from nmsid.protocols.session_publish import stale_temps
    path = tmp_path / "P01.h5"
    path.write_bytes(b"")
    for name in ("P01.h5.writing-12", "P01.h5.recovering-13", "P01.h5.writing-x",
                 "P02.h5.writing-14"):
        (tmp_path / name).write_bytes(b"")
    found = sorted(p.name for p in stale_temps(str(path)))
    assert found == ["P01.h5.recovering-13", "P01.h5.writing-12"]


def test_a_trial_in_progress_whose_stream_is_gone_is_kept_as_aborted_and_empty(tmp_path):
    path = tmp_path / "P01.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    log.end_trial(_trial(0))
    log.begin_trial(_trial(1))
    log.close()                                       # a kill during trial 2
    (journal_dir(path) / "partial.f64").unlink()       # its stream lost, its metadata kept
    rep = recover(path)
    s = read_session(path)
    assert len(s.trials) == 2 and s.trials[1].status == "aborted"
    assert s.trials[1].n_samples == 0 and rep.partial_recovered
    assert "the trial in progress was kept as aborted (0 samples)" in rep.summary()


def test_the_report_keeps_what_was_wrong_before_recovery(tmp_path):
    from nmsid.protocols.session_file import validate_session
    path = _killed_session(tmp_path)
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    before = validate_session(path)
    rep = recover(path)
    assert before and rep.problems_before == before


def test_a_journal_without_its_calibration_is_refused_not_built_into_a_file(tmp_path):
    # the callers restore the calibration first; a journal that still has none is refused
    # by name (it used to reach write_calibration(None): an AttributeError)
    from nmsid.protocols.session_file import SessionFileError
    from nmsid.rig.journal import JournalContents
    from nmsid.rig.recovery import _build_from_journal
    jc = JournalContents(header={"participant": "P01", "created_utc": "2026-01-01T00:00:00Z"},
                         calibration=None, events=[], trial_files=[])
    with pytest.raises(SessionFileError, match="no calibration to rebuild"):
        _build_from_journal(tmp_path / "s.h5", jc, [])
    assert not (tmp_path / "s.h5").exists()


def test_the_damaged_file_is_kept_aside_on_a_volume_without_hard_links(tmp_path,
                                                                       monkeypatch):
    """FAT / exFAT (a USB stick) have no hard links: the damaged file is then renamed
    aside, never lost."""
    import errno  # noqa: PLC0415
    path = _killed_session(tmp_path)
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    damaged = path.read_bytes()

    def no_link(src, dst, *a, **kw):
        raise OSError(errno.EPERM, "hard links not supported on this volume")
    monkeypatch.setattr(os, "link", no_link)
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.damaged_kept_at
    with open(rep.damaged_kept_at, "rb") as fh:
        assert fh.read() == damaged
    assert len(read_session(path).trials) == 2


def _twin_trials_session(tmp_path):
    """Two trials whose samples are identical (a deterministic simulation) at two
    schedule positions: they are two trials, not one recorded twice."""
    path = tmp_path / "P02.h5"
    log = SessionLog.create(path, participant="P02", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    for i in range(2):
        t = _trial(0)
        t.extra_attrs = {"schedule_index": i}
        log.end_trial(t)
    log.close()
    return path


def test_two_trials_with_the_same_samples_at_two_schedule_positions_are_both_kept(tmp_path):
    path = _twin_trials_session(tmp_path)
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.n_trials == 2
    got = read_session(path).trials
    assert [int(np.asarray(t.extra_attrs["schedule_index"])) for t in got] == [0, 1]


def test_recovery_leaves_journal_entries_already_in_place_untouched(tmp_path):
    """A rebuild from an intact journal rewrites no entry (no disk space, no time, no
    window in which an entry is being replaced)."""
    path = _killed_session(tmp_path, n_trials=3)
    jdir = journal_dir(path)
    before = {p.name: (os.stat(p).st_ino, os.stat(p).st_mtime_ns)
              for p in sorted(jdir.glob("trial-*.npz"))}
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    assert recover(path).action == "rebuilt"
    after = {p.name: (os.stat(p).st_ino, os.stat(p).st_mtime_ns)
             for p in sorted(jdir.glob("trial-*.npz"))}
    assert len(before) == 3 and after == before


def test_a_rebuild_keeps_a_file_at_the_sessions_name_until_the_new_one_replaces_it(
        tmp_path, monkeypatch):
    """The damaged file is kept aside by a second name (a hard link), not moved: a kill
    at any instant of the rebuild leaves a session file at its name, and the rebuilt
    one takes the name in one atomic replace."""
    path = _killed_session(tmp_path)
    with open(path, "r+b") as fh:
        fh.write(b"\0" * 64)
    seen: list[bool] = []
    real_replace = os.replace

    def spy_replace(src, dst, *a, **kw):
        if os.path.abspath(dst) == os.path.abspath(path):
            seen.append(os.path.lexists(path))
        return real_replace(src, dst, *a, **kw)
    monkeypatch.setattr(os, "replace", spy_replace)
    rep = recover(path)
    assert rep.action == "rebuilt" and os.path.exists(rep.damaged_kept_at)
    assert seen == [True]


def test_the_summary_says_every_outcome_in_its_own_words():
    """The operator reads recovery's one line: each outcome and each problem named,
    singular and plural right (closed-form strings, no file needed)."""
    from nmsid.rig.recovery import RecoveryReport  # noqa: PLC0415
    assert RecoveryReport("s.h5", "no-calibration").summary() == (
        "s.h5: the session ended before calibration finished; there is no data to recover "
        "(resume it to start again)")
    assert RecoveryReport("s.h5", "appended", n_trials=5, n_appended=2).summary() == (
        "s.h5: 2 trial(s) missing from the file were appended; 5 trials in the file")
    one = RecoveryReport("s.h5", "rebuilt", n_trials=3, partial_recovered=True,
                         partial_samples=120, header_rebuilt="header.json rebuilt",
                         unreadable=["trial-0002.npz (unreadable: x): kept from the file's t002"],
                         deleted=["trial-0003.npz (deleted): lost"], lost=["trial-0003.npz"],
                         conflicts=["trial-0001.npz and the file's t001 differ (both kept)"],
                         orphans=["old.h5.journal has no session file"])
    assert one.summary() == (
        "s.h5: rebuilt from the journal; 3 trials in the file"
        "; the trial in progress was kept as aborted (120 samples)"
        "; header.json rebuilt"
        "; 1 unreadable journal entry (kept aside as unreadable-<name>.at-<time>): "
        "trial-0002.npz (unreadable: x): kept from the file's t002"
        "; deleted journal entries: trial-0003.npz (deleted): lost"
        "; 1 trial(s) lost (in no readable copy; `run --resume` runs them again)"
        "; trial-0001.npz and the file's t001 differ (both kept)"
        "; note: old.h5.journal has no session file")
    two = RecoveryReport("s.h5", "rebuilt", n_trials=4, unreadable=["a", "b"])
    assert two.summary() == ("s.h5: rebuilt from the journal; 4 trials in the file; 2 "
                             "unreadable journal entries (kept aside as "
                             "unreadable-<name>.at-<time>): a; b")
