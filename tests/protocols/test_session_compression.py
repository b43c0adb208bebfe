"""Compressed session files: lossless, readable as before, old uncompressed files still valid."""

from __future__ import annotations

import numpy as np
import pytest

from nmsid.protocols.session_file import (
    Calibration,
    SessionWriter,
    Trial,
    read_session,
    validate_session,
)


def _trial(rng, n, *, scale, wrench_f32):
    w = rng.normal(0, scale, (n, 6))
    if wrench_f32:
        w = w.astype(np.float32).astype(np.float64)  # e.g. a sensor reporting float32
    return Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=rng.uniform(0, 1, n),
                 I_ext_mA=rng.uniform(0, 12, n), I_flex_mA=rng.uniform(0, 12, n),
                 force_N=rng.normal(0, scale, n), wrench=w,
                 sync=np.round(rng.uniform(0, 5, n), 2))


def _write(path, trials, gzip_level):
    w = SessionWriter.create(path, participant="P1", gzip_level=gzip_level)
    w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0,
                                    ramps={"ext_I_mA": np.linspace(0, 9, 33)}))
    for t in trials:
        w.append_trial(t)


@pytest.mark.parametrize("level", [None, 1, 4, 9])
@pytest.mark.parametrize("n,scale,wrench_f32", [(70000, 1e-3, False), (3001, 40.0, True),
                                                (0, 1.0, False), (1, 1e6, True)])
def test_round_trip_is_bit_exact(tmp_path, level, n, scale, wrench_f32):
    rng = np.random.default_rng(n + int(scale))
    trials = [_trial(rng, n, scale=scale, wrench_f32=wrench_f32) for _ in range(2)]
    path = tmp_path / "s.h5"
    _write(path, trials, level)
    back = read_session(path)
    assert validate_session(path) == []
    for a, b in zip(trials, back.trials, strict=True):
        for key in ("rE", "I_ext_mA", "I_flex_mA", "force_N", "wrench", "sync"):
            got, want = getattr(b, key), np.asarray(getattr(a, key), dtype=np.float64)
            assert got.dtype == np.float64
            np.testing.assert_array_equal(got, want)


def test_filters_and_narrowing_only_where_lossless(tmp_path):
    import h5py
    rng = np.random.default_rng(3)
    path = tmp_path / "s.h5"
    trials = [_trial(rng, 5000, scale=2.0, wrench_f32=True),
              _trial(rng, 5000, scale=2.0, wrench_f32=False)]
    for t in trials:  # signals with redundancy, as real commands and A/D records have
        t.rE = np.round(t.rE, 2)
        t.force_N = np.round(t.force_N * 256) / 256  # binary steps, few distinct values
    _write(path, trials, 4)
    with h5py.File(path, "r") as f:
        for name in ("t001", "t002"):
            for key in ("rE", "force_N"):
                d = f[f"trials/{name}/{key}"]
                assert d.compression == "gzip" and d.shuffle and d.compression_opts == 4
            assert f[f"trials/{name}/force_N"].dtype == np.float64  # the contract's type
        assert f["trials/t001/wrench"].dtype == np.float32   # float32-exact values
        assert f["trials/t002/wrench"].dtype == np.float64   # would lose bits as float32
        assert f["trials/t001/sync"].dtype != np.float32      # 0.01 steps are not float32


def test_incompressible_dataset_stays_plain(tmp_path):
    """Full-mantissa float64 noise deflates by ~15 %: not worth slower reads."""
    import h5py
    rng = np.random.default_rng(8)
    t = _trial(rng, 20000, scale=1.0, wrench_f32=False)
    t.I_ext_mA = np.full(20000, 3.0)
    _write(tmp_path / "s.h5", [t], 4)
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f["trials/t001/force_N"].compression is None
        assert f["trials/t001/I_ext_mA"].compression == "gzip"
    np.testing.assert_array_equal(read_session(tmp_path / "s.h5").trials[0].force_N, t.force_N)


def test_compressed_is_smaller_for_redundant_data(tmp_path):
    n = 30000
    t = Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=np.full(n, 0.5), I_ext_mA=np.full(n, 3.0),
              I_flex_mA=np.full(n, 2.0), force_N=np.round(np.sin(np.arange(n) / 50), 3))
    _write(tmp_path / "old.h5", [t], None)
    _write(tmp_path / "new.h5", [t], 4)
    assert (tmp_path / "new.h5").stat().st_size < (tmp_path / "old.h5").stat().st_size / 4


def test_old_uncompressed_file_reads_and_validates(tmp_path):
    """A file written the old way (plain float64 datasets, made with bare h5py)."""
    import h5py
    path = tmp_path / "old.h5"
    rng = np.random.default_rng(9)
    force = rng.normal(size=400)
    with h5py.File(path, "w") as f:
        for k, v in (("format", "nmsid-session"), ("participant", "OLD1"),
                     ("created_utc", "2025-01-01T00:00:00Z"), ("software", "nmsid 0.0")):
            f.attrs[k] = v
        f.attrs["format_version"] = 1
        c = f.create_group("calibration")
        for k, v in zip(("Iemin_mA", "Iemax_mA", "Ifmin_mA", "Ifmax_mA", "Fmin_N", "Fmax_N"),
                        (1.0, 9.0, 1.5, 10.0, 0.5, 5.0), strict=True):
            c.attrs[k] = v
        g = f.create_group("trials/t001")
        for k, v in (("sE", 0.4), ("fs_Hz", 2000.0), ("steady_s", 5.0), ("chirp_s", 10.0),
                     ("chirp_f0_Hz", 1.0), ("chirp_f1_Hz", 10.0), ("carrier_Hz", 1000.0)):
            g.attrs[k] = v
        g.attrs["repeat"] = 1
        for k, v in (("status", "completed"), ("abort_reason", ""),
                     ("started_utc", "2025-01-01T00:00:05Z")):
            g.attrs[k] = v
        for k in ("rE", "I_ext_mA", "I_flex_mA"):
            g.create_dataset(k, data=np.zeros(400))
        g.create_dataset("force_N", data=force)
        g.create_dataset("wrench", data=rng.normal(size=(400, 6)))
        assert g["force_N"].compression is None
    assert validate_session(path) == []
    s = read_session(path)
    np.testing.assert_array_equal(s.trials[0].force_N, force)
    assert s.trials[0].wrench.shape == (400, 6)


def test_cli_validate_accepts_old_and_new(tmp_path, capsys):
    from nmsid.cli import main
    rng = np.random.default_rng(4)
    for name, level in (("old.h5", None), ("new.h5", 4)):
        _write(tmp_path / name, [_trial(rng, 1000, scale=1.0, wrench_f32=False)], level)
    assert main(["validate", str(tmp_path / "old.h5"), str(tmp_path / "new.h5")]) == 0
    assert capsys.readouterr().out.count("valid nmsid session file") == 2


def test_bad_level_is_refused(tmp_path):
    with pytest.raises(ValueError, match="gzip_level 12"):
        SessionWriter(tmp_path / "x.h5", gzip_level=12)
