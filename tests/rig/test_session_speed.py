"""The fast-session changes keep the journal's format and every durability check:
the journal's entries (numpy's savez_compressed), the end-of-session check of the file,
the engine letting go of reported trials."""

import zipfile
from pathlib import Path

import h5py
import numpy as np

from nmsid.protocols.session_file import Calibration, Trial, read_session
from nmsid.rig import journal, session_log
from nmsid.rig.engine import Engine, EngineObserver
from nmsid.rig.session_log import SessionLog, file_trial_digests, journal_dir, trial_digest


def _trial(i, n=3000):
    rng = np.random.default_rng(i)
    k = np.arange(n)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=0.5 + 0.5 * np.sin(k / 50.0),
                 I_ext_mA=np.round(np.abs(np.sin(k / 70.0)) * 40) / 4,
                 I_flex_mA=np.zeros(n), force_N=rng.normal(size=n),
                 wrench=(np.rint(rng.normal(size=(n, 6)) * 300) + 0.0) * 0.015625,
                 sync=np.where(k < n // 2, 5.0, 0.0), started_utc="2026-11-22T01:00:00Z",
                 extra_attrs={"schedule_index": i})


SIGNALS = ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync")


def test_a_journal_entry_is_a_plain_zip_and_reads_back_bit_for_bit(tmp_path):
    t = _trial(1)
    p = tmp_path / "trial-0001.npz"
    journal.save_trial_npz(p, t)
    with zipfile.ZipFile(p) as z:
        assert z.testzip() is None       # every member's CRC-32 right
        info = {i.filename: i for i in z.infolist()}
    assert set(info) == {f"{k}.npy" for k in SIGNALS} | {"__enc__.npy", "__meta__.npy"}
    assert info["rE.npy"].compress_type == zipfile.ZIP_DEFLATED
    assert info["I_ext_mA.npy"].compress_type == zipfile.ZIP_DEFLATED
    assert info["I_ext_mA.npy"].compress_size < 0.5 * info["I_ext_mA.npy"].file_size
    back = journal.load_trial_npz(p)
    for k in SIGNALS:
        assert np.array_equal(getattr(back, k), getattr(t, k)), k
    assert back.sE == t.sE and back.extra_attrs == t.extra_attrs


def test_an_entry_is_numpys_own_savez_compressed_of_the_encoded_members(tmp_path):
    t = _trial(2)
    p = tmp_path / "e.npz"
    journal.save_trial_npz(p, t)
    expected = journal.trial_members(t)
    with np.load(p, allow_pickle=False) as z:
        assert sorted(z.files) == sorted(expected)
        for name, arr in expected.items():
            assert z[name].dtype == arr.dtype and np.array_equal(z[name], arr), name
        enc = journal.json.loads(str(z["__enc__"]))
    assert enc["wrench"]["dtype"] == "<i2"   # A/D counts


DATA = Path(__file__).resolve().parent / "data"


def test_an_entry_of_the_former_zip_writer_still_reads_back_bit_for_bit():
    # written by the hand-made zip writer (run-length deflate strategy) before numpy's
    # savez replaced it, from _trial(7, n=400): a journal left by that version is recovered
    back = journal.load_trial_npz(DATA / "journal-entry-shuffled-deflate.npz")
    t = _trial(7, n=400)
    for k in SIGNALS:
        if k == "rE":   # 0.5 + 0.5 sin: the file's sin is Linux's, this platform's libm
            # may differ by an ulp of sin (<= 1.1e-16; under Wine up to 16 ulp of rE near 0)
            np.testing.assert_allclose(back.rE, t.rE, rtol=0, atol=1e-15)
            continue
        assert np.array_equal(getattr(back, k), getattr(t, k)), k
    assert back.sE == t.sE and back.extra_attrs == t.extra_attrs


def test_a_plain_npz_entry_without_encoding_still_reads(tmp_path):
    t = _trial(4, n=50)
    p = tmp_path / "plain.npz"
    np.savez(p, __meta__=np.array(journal.json.dumps(journal.trial_meta(t))),
             **{k: getattr(t, k) for k in SIGNALS})
    back = journal.load_trial_npz(p)
    assert all(np.array_equal(getattr(back, k), getattr(t, k)) for k in SIGNALS)


def _session(tmp_path, n_trials=2):
    path = tmp_path / "P01.h5"
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10, ramps={"ext_I_mA": np.arange(3.0)}))
    trials = [_trial(i) for i in range(n_trials)]
    for t in trials:
        log.end_trial(t)
    return path, log, trials


def test_file_trial_digests_are_the_trials_digests_in_file_order(tmp_path):
    path, log, trials = _session(tmp_path, 3)
    assert log.finish()
    assert file_trial_digests(path) == [trial_digest(t) for t in trials] \
        == [trial_digest(t) for t in read_session(path).trials]


def test_finish_keeps_the_journal_when_a_trial_in_the_file_differs(tmp_path, monkeypatch):
    path, log, _ = _session(tmp_path)
    publish = SessionLog.publish

    def publish_then_change(self, **kw):
        ok = publish(self, **kw)
        with h5py.File(path, "a") as f:   # valid checksums, one sample different
            f["trials/t002/force_N"][5] += 1.0
        return ok

    monkeypatch.setattr(SessionLog, "publish", publish_then_change)
    assert log.finish() is False
    assert journal_dir(path).is_dir() and len(list(journal_dir(path).glob("trial-*"))) == 2


def test_finish_keeps_the_journal_when_the_file_does_not_validate(tmp_path, monkeypatch):
    path, log, _ = _session(tmp_path)
    monkeypatch.setattr(session_log, "validate_session", lambda p: ["a problem"])
    assert log.finish() is False
    assert journal_dir(path).is_dir()


def test_finish_keeps_the_journal_when_the_data_cannot_be_read(tmp_path, monkeypatch):
    path, log, _ = _session(tmp_path)

    def unreadable(p):
        raise OSError("checksum mismatch")

    monkeypatch.setattr(session_log, "file_trial_digests", unreadable)
    assert log.finish() is False
    assert journal_dir(path).is_dir()


class _Levels(EngineObserver):
    def __init__(self):
        self.levels = []

    def on_level_completed(self, sE, trials):
        self.levels.append((sE, [t.force_N.size for t in trials]))


def test_the_engine_lets_go_of_a_reported_levels_samples(tmp_path, fake_rig, small_config):
    obs = _Levels()
    eng = Engine(small_config(), fake_rig(), tmp_path / "s.h5", observer=obs)
    summary = eng.run()
    assert summary.complete and len(obs.levels) == len({p.sE for p in eng.schedule})
    assert all(n > 0 for _, sizes in obs.levels for n in sizes)  # observers got samples
    kept = list(eng._trials_this_run.values())
    assert kept and not any(isinstance(t, Trial) for t in kept)
    assert summary.completed_names == [f"t{i + 1:03d}" for i in range(len(eng.schedule))]

