"""Recovery keeps every good trial (issue 26, 1): the published file and the journal are
merged trial by trial; a damaged or deleted entry is named and never costs a trial the
file still has; a damaged header is rebuilt from the file; resume repeats no trial."""

import json
import os

import h5py
import numpy as np
import pytest

from nmsid.protocols.session_file import (
    Calibration,
    SessionFileError,
    Trial,
    read_session,
    validate_session,
)
from nmsid.protocols.session_state import session_state
from nmsid.protocols.user_values import (
    DERIVED_SUFFIXES,
    MAX_SESSION_NAME_BYTES,
    name_length_problem,
)
from nmsid.rig.journal import load_trial_npz, save_trial_npz, trial_digest
from nmsid.rig.session_log import SessionLog, journal_dir, recover


def _trial(i, n=300):
    rng = np.random.default_rng(100 + i)
    lsb = 20.0 / 65536
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rng.random(n),
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i},
                 wrench=np.rint(rng.normal(scale=300, size=(n, 6))) * lsb,
                 sync=(rng.random(n) > 0.5) * 5.0)


def _session(path, n_trials, published=None):
    """A session of ``n_trials`` journaled trials whose file holds the first
    ``published`` (default all), then the writer 'killed' (nothing more published)."""
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    trials = [_trial(i) for i in range(n_trials)]
    for i, t in enumerate(trials):
        log.end_trial(t)
        if published is not None and i + 1 == published:
            assert log.publish() is True
    log.close(publish=published is None)
    return trials


def _indexes(path):
    return [int(t.extra_attrs["schedule_index"]) for t in read_session(path).trials]


def _same(a: Trial, b: Trial) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k))
               for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync"))


@pytest.mark.parametrize("damage", ["overwrite", "truncate", "delete"])
def test_a_damaged_entry_never_costs_a_trial_the_valid_file_holds(tmp_path, damage):
    path = tmp_path / "S.h5"
    trials = _session(path, 6)
    assert validate_session(path) == [] and len(read_session(path).trials) == 6
    entry = journal_dir(path) / "trial-0003.npz"
    if damage == "overwrite":
        entry.write_bytes(os.urandom(entry.stat().st_size))
    elif damage == "truncate":
        entry.write_bytes(entry.read_bytes()[:200])
    else:
        entry.unlink()
    good = path.read_bytes()
    rep = recover(path)
    assert rep.action == "none" and rep.n_trials == 6 and not rep.lost
    assert path.read_bytes() == good and not rep.damaged_kept_at  # the good file is kept
    text = rep.summary()
    assert "trial-0003.npz" in text and "kept from the file's t003" in text
    assert ("deleted" if damage == "delete" else "unreadable") in text
    assert _indexes(path) == list(range(6))
    # the journal again holds every trial (the entry rewritten from the file)
    assert _same(load_trial_npz(entry), trials[2])
    if damage != "delete":  # the damaged entry is kept aside, by name
        assert [p.name.split(".at-")[0] for p in journal_dir(path).glob("unreadable-*")] == \
            ["unreadable-trial-0003.npz"]
    # resume repeats nothing: every schedule index is done
    log, _ = SessionLog.resume(path)
    done = sorted(int(m["extra_attrs"]["schedule_index"]) for m in log.trials)
    assert done == list(range(6))
    log.close()


def test_a_killed_session_merges_file_and_journal_and_names_the_lost_trial(tmp_path):
    path = tmp_path / "S.h5"
    trials = _session(path, 6, published=3)  # file: t001-t003; journal: 6 entries
    jdir = journal_dir(path)
    assert session_state(path).label == "incomplete"
    (jdir / "trial-0002.npz").write_bytes(b"PK\x03\x04garbage")  # in the file: kept
    (jdir / "trial-0005.npz").unlink()                          # only in the journal: lost
    rep = recover(path)
    assert rep.action == "appended" and rep.n_trials == 5 and rep.n_appended == 2
    assert rep.lost == ["trial-0005.npz"]
    text = rep.summary()
    assert "trial-0002.npz (unreadable" in text and "kept from the file's t002" in text
    assert "trial-0005.npz (deleted): not in the file" in text and "1 trial(s) lost" in text
    assert _indexes(path) == [0, 1, 2, 3, 5]
    s = read_session(path)
    assert all(_same(a, trials[i]) for a, i in zip(s.trials, [0, 1, 2, 3, 5], strict=True))
    # the journal now equals the file, entry by entry, numbered without a gap
    entries = sorted(jdir.glob("trial-*.npz"))
    assert [p.name for p in entries] == [f"trial-{k:04d}.npz" for k in range(1, 6)]
    assert [trial_digest(load_trial_npz(p)) for p in entries] == \
        [trial_digest(t) for t in s.trials]
    assert session_state(path).label == "finished"
    # a second recovery changes nothing
    before = path.read_bytes()
    assert recover(path).action == "none" and path.read_bytes() == before
    log, _ = SessionLog.resume(path)
    assert sorted(int(m["extra_attrs"]["schedule_index"]) for m in log.trials) == \
        [0, 1, 2, 3, 5]  # index 4 is the only one run again
    log.close()


def test_a_damaged_file_trial_and_another_damaged_entry_are_both_kept(tmp_path):
    path = tmp_path / "S.h5"
    trials = _session(path, 4)
    data = bytearray(path.read_bytes())  # flip one byte of t001's force data on disk
    at = data.find(trials[0].force_N.tobytes()[:64])  # random normals: stored as they are
    assert at > 0
    data[at + 40] ^= 0xFF
    path.write_bytes(bytes(data))
    assert validate_session(path)
    (journal_dir(path) / "trial-0003.npz").write_bytes(b"")
    rep = recover(path)
    assert rep.action == "rebuilt" and rep.damaged_kept_at and not rep.lost
    s = read_session(path)
    assert validate_session(path) == [] and len(s.trials) == 4
    assert all(_same(a, b) for a, b in zip(s.trials, trials, strict=True))


def test_file_and_journal_holding_different_samples_are_both_kept_and_named(tmp_path):
    """The merge compares samples (CRC), not only the schedule index."""
    path = tmp_path / "S.h5"
    _session(path, 3)
    other = _trial(1)
    other.force_N = other.force_N + 1.0  # same schedule index, other samples
    save_trial_npz(journal_dir(path) / "trial-0002.npz", other)
    with h5py.File(path, "r+") as f:  # and make the file need a rebuild
        f["trials/t003"].attrs["sE"] = np.nan
    rep = recover(path)
    assert "trial-0002.npz and the file's t002 differ (both kept)" in rep.summary()
    assert len(read_session(path).trials) == 4


@pytest.mark.parametrize("damage", ["garbage", "missing", "not an object"])
def test_a_damaged_header_is_rebuilt_from_the_file(tmp_path, damage):
    path = tmp_path / "S.h5"
    _session(path, 4, published=2)
    hp = journal_dir(path) / "header.json"
    original = json.loads(hp.read_text("utf-8"))
    {"garbage": lambda: hp.write_bytes(b"\x00{{not json"), "missing": hp.unlink,
     "not an object": lambda: hp.write_text("[1, 2]", "utf-8")}[damage]()
    rep = recover(path)
    assert rep.header_rebuilt and "rebuilt from the session file" in rep.summary()
    assert rep.n_trials == 4 and _indexes(path) == [0, 1, 2, 3]
    header = json.loads(hp.read_text("utf-8"))
    for key in ("participant", "created_utc", "config_json", "seed", "backend"):
        assert header[key] == original[key], key
    assert header["extra_attrs"]["schedule_json"] == "[]"
    log, _ = SessionLog.resume(path)  # resume works from the rebuilt header
    assert len(log.trials) == 4
    log.close()


def test_a_damaged_header_without_a_file_is_one_line_with_advice(tmp_path):
    path = tmp_path / "S.h5"
    _session(path, 2)
    path.unlink()
    (journal_dir(path) / "header.json").write_text("{oops", "utf-8")
    for attempt in (lambda: recover(path), lambda: SessionLog.resume(path)):
        with pytest.raises(SessionFileError) as err:
            attempt()
        text = str(err.value)
        assert "\n" not in text and "header.json: is damaged" in text
        assert "restore the file or header.json from a backup" in text
    assert len(list(journal_dir(path).glob("trial-*.npz"))) == 2  # left as they were


def test_the_trial_in_progress_is_kept_after_a_deleted_entry(tmp_path):
    path = tmp_path / "S.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    for i in range(3):
        log.end_trial(_trial(i))
    log.begin_trial(Trial(sE=0.9, repeat=1, fs_Hz=2000.0, rE=[], I_ext_mA=[],
                          I_flex_mA=[], force_N=[], extra_attrs={"schedule_index": 7}))
    x = np.arange(50) / 100.0
    log.append_chunk(force_N=x, rE=x, I_ext_mA=x, I_flex_mA=x)
    log.close(publish=False)
    (journal_dir(path) / "trial-0002.npz").unlink()  # in no file: lost, but the rest kept
    rep = recover(path)
    assert rep.partial_recovered and rep.partial_samples == 50
    assert _indexes(path) == [0, 2, 7]
    assert read_session(path).trials[-1].status == "aborted"


def test_validate_says_incomplete_then_live_and_cleans_leftovers(tmp_path, capsys):
    from nmsid.cli import main
    path = tmp_path / "S.h5"
    _session(path, 3, published=1)
    done = tmp_path / "S.h5.journal.done-4242"
    done.mkdir()
    (done / "trial-0001.npz").write_bytes(b"x")
    (tmp_path / "S.h5.writing-4243").write_bytes(b"x")
    assert main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "INCOMPLETE" in out and "the journal holds 3 trial(s), the file 1" in out
    assert f"nmsid recover {path}" in out
    assert "removed leftovers" in out and "S.h5.journal.done-4242" in out
    assert not done.exists() and not (tmp_path / "S.h5.writing-4243").exists()
    recover(path)
    assert main(["validate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "INCOMPLETE" not in out and "LIVE" not in out


def test_the_longest_derived_name_fits_or_the_name_is_refused(tmp_path):
    """The one name limit (protocols.user_values): the longest accepted session name plus
    each derived suffix can really be created; one byte more is refused in one line."""
    ok = tmp_path / ("a" * MAX_SESSION_NAME_BYTES)
    assert name_length_problem(str(ok)) is None
    for length in DERIVED_SUFFIXES.values():
        (tmp_path / (ok.name + "x" * length)).write_bytes(b"")
    bad = tmp_path / ("é" * (MAX_SESSION_NAME_BYTES // 2 + 1))  # 2 bytes each
    problem = name_length_problem(str(bad))
    assert problem is not None and "bytes long" in problem and "\n" not in problem


def test_a_rebuild_keeps_the_damaged_file_in_place_until_the_new_one_replaces_it(
        tmp_path, monkeypatch):
    """A kill during the rebuild's publish must leave the session file where it was (a
    hard link keeps the aside copy; moving it aside first would leave no file)."""
    import nmsid.protocols.session_writer as sw
    path = tmp_path / "S.h5"
    _session(path, 2)
    data = bytearray(path.read_bytes())
    data[:8] = b"\0" * 8  # the HDF5 signature scribbled over
    path.write_bytes(bytes(data))
    seen = []
    real = sw.publish_image

    def spy(p, image, **kw):
        seen.append(os.path.exists(p))
        return real(p, image, **kw)
    monkeypatch.setattr(sw, "publish_image", spy)
    rep = recover(path)
    assert rep.action == "rebuilt" and seen == [True]
    assert os.path.getsize(rep.damaged_kept_at) == len(data)


def test_the_preflight_asks_for_the_journal_and_one_final_file_not_three_copies():
    from nmsid.rig.session_log import expected_session_bytes
    trial = 8 * 30_000 * 11 + 64 * 1024  # one trial as float64 at worst, 11 columns
    assert expected_session_bytes(45, 30_000) == int(1.2 * 45 * trial * 2) + (4 << 20)
    # resuming: the file already there stays until the new version replaces it
    assert expected_session_bytes(10, 30_000, file_bytes=5_000_000) == \
        int(1.2 * (10 * trial * 2 + 2 * 5_000_000)) + (4 << 20)


def test_run_resume_with_a_damaged_header_is_one_line_or_rebuilds_it(tmp_path, capsys):
    from nmsid.cli import main
    from nmsid.rig.recovery import check_stored_header
    path = tmp_path / "S.h5"
    _session(path, 2)
    hp = journal_dir(path) / "header.json"
    hp.write_text('{"partic', "utf-8")
    check_stored_header(path)  # the file gives it back
    assert json.loads(hp.read_text("utf-8"))["participant"] == "P01"
    hp.write_text('{"partic', "utf-8")
    path.unlink()
    code = main(["run", "--backend", "sim", "--resume", str(path), "--no-identify"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and "JSONDecodeError" not in err
    assert err.strip().splitlines()[-1].startswith(f"nmsid: error: {hp}: is damaged")
