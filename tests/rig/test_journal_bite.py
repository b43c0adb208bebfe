"""Tests that bite (issue 29, 5) for the journal's layout (rig/journal.py): an A/D channel
journaled as its counts (the journal costs about what the file does), and a stream
metadata file that is torn or foreign is not streamed into. Behaviour only: what is read
back and what the entry costs on disk."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from nmsid.protocols.session_file import Trial
from nmsid.rig.journal import PARTIAL_COLUMNS, load_trial_npz, read_journal, save_trial_npz

N = 2000


def _ad_trial() -> Trial:
    """A trial whose wrench (6 axes, 16-bit A/D codes x LSB) and sync line (0 / 5 V) are
    A/D readings; the other signals are float noise (on no grid)."""
    rng = np.random.default_rng(29)
    lsb = np.array([0.0123, 0.0123, 0.0311, 0.00071, 0.00071, 0.00093])
    wrench = rng.integers(-30000, 30000, size=(N, 6)) * lsb
    sync = np.where(rng.random(N) < 0.5, 0.0, 5.0)
    return Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=rng.random(N), I_ext_mA=rng.random(N),
                 I_flex_mA=rng.random(N), force_N=rng.normal(size=N), wrench=wrench,
                 sync=sync, started_utc="2026-11-25T02:00:00Z")


def test_an_ad_wrench_and_sync_are_journaled_as_counts_and_read_back_bit_for_bit(tmp_path):
    t = _ad_trial()
    entry = tmp_path / "trial-0001.npz"
    save_trial_npz(entry, t)
    back = load_trial_npz(entry)
    for k in ("wrench", "sync", "force_N", "rE"):
        assert np.array_equal(getattr(back, k), getattr(t, k)), k
        assert getattr(back, k).dtype == np.float64
    with zipfile.ZipFile(entry) as zf:
        stored = {i.filename: i.compress_size for i in zf.infolist()}
    # 16-bit codes: at most 2 bytes a sample (+ the .npy header); float64 would be ~6
    assert stored["wrench.npy"] <= 2 * 6 * N + 512, stored
    assert stored["sync.npy"] <= N + 512, stored


def _journal(tmp_path, pmeta_text: str):
    jdir = tmp_path / "P01.h5.journal"
    jdir.mkdir()
    (jdir / "header.json").write_text("{}", encoding="utf-8")
    (jdir / "partial.json").write_text(pmeta_text, encoding="utf-8")
    (jdir / "partial.f64").write_bytes(np.zeros(8).tobytes())
    return jdir


def test_a_sound_stream_metadata_file_is_streamed_into(tmp_path):
    pmeta = {"columns": list(PARTIAL_COLUMNS), "sE": 0.5, "repeat": 1, "fs_Hz": 2000.0}
    jc = read_journal(_journal(tmp_path, json.dumps(pmeta)))
    assert jc.partial_meta == pmeta and jc.partial_path == tmp_path / "P01.h5.journal" / \
        "partial.f64"


@pytest.mark.parametrize("text", [
    '["force_N", "rE", "I_ext_mA", "I_flex_mA"]',               # not an object
    '{"columns": "force_N rE I_ext_mA I_flex_mA"}',             # columns not a list
    json.dumps({"columns": dict.fromkeys(PARTIAL_COLUMNS, 1)}),  # columns not a list
    json.dumps({"columns": list(PARTIAL_COLUMNS[:-1])}),         # a column missing
    '{"columns": ["force_N", "rE", "I_ext',                      # torn by a kill
])
def test_a_torn_or_foreign_stream_metadata_file_is_not_streamed_into(tmp_path, text):
    jc = read_journal(_journal(tmp_path, text))
    assert jc.partial_meta is None and jc.partial_path is None


def test_a_plain_entry_without_encodings_is_read_back(tmp_path):
    """Entries written before the counts encoding (``np.savez`` of the arrays and the
    metadata, no ``__enc__``) still read back, signal for signal."""
    from nmsid.rig.journal import trial_meta  # noqa: PLC0415
    t = _ad_trial()
    entry = tmp_path / "trial-0001.npz"
    np.savez(entry, __meta__=np.array(json.dumps(trial_meta(t))), rE=t.rE,
             I_ext_mA=t.I_ext_mA, I_flex_mA=t.I_flex_mA, force_N=t.force_N, wrench=t.wrench,
             sync=t.sync)
    back = load_trial_npz(entry)
    for k in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync"):
        assert np.array_equal(getattr(back, k), getattr(t, k)), k
    assert back.sE == t.sE and back.started_utc == t.started_utc


def test_numpy_values_in_an_entrys_metadata_are_written_as_json_lists():
    from nmsid.rig.journal import json_default
    text = json.dumps({"limits_mA": np.array([1.5, 16.0]), "n": np.int64(3),
                       "note": b"ok"}, default=json_default)
    assert json.loads(text) == {"limits_mA": [1.5, 16.0], "n": 3, "note": "ok"}
    with pytest.raises(TypeError, match="not JSON-able: object"):
        json.dumps({"x": object()}, default=json_default)


def test_a_journal_header_that_is_not_a_json_object_is_refused_by_name(tmp_path):
    from nmsid.protocols.session_file import SessionFileError
    jdir = tmp_path / "S.h5.journal"
    jdir.mkdir()
    (jdir / "header.json").write_text("[1, 2]", encoding="utf-8")
    with pytest.raises(SessionFileError, match=r"header\.json.*damaged \(not a JSON object\)"):
        read_journal(jdir)
