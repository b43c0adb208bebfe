"""The low-level reads of :mod:`nmsid.protocols.session_h5` give exactly what h5py's
high-level API gives (values and types), for every kind of attribute and dataset a session
file may hold, its own writer's and other labs' (fixed-length strings, float32, arrays,
big-endian, empty)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from nmsid.protocols.session_h5 import (
    float64_buffers,
    has_attr,
    open_group,
    open_member,
    read_attrs,
    read_float64,
)

ATTRS = {
    "f64": np.float64(2000.0),
    "f32": np.float32(1.5),
    "f64_be": np.array(3.25, dtype=">f8"),
    "i64": np.int64(3),
    "i32": np.int32(-7),
    "u8": np.uint8(200),
    "bool": np.bool_(True),
    "vlen_utf8": "μ-Stim: ok",
    "vlen_ascii": h5py.string_dtype("ascii"),   # created below with its own dtype
    "fixed": np.bytes_(b"MATLAB"),
    "array_f64": np.array([1.0, 2.0, 3.0]),
    "one_f64": np.array([4.0]),
    "array_str": np.array(["a", "b"], dtype=h5py.string_dtype()),
    "empty": h5py.Empty("f8"),
    "bad_utf8": None,                            # created below: invalid UTF-8 bytes
}


@pytest.fixture()
def h5file(tmp_path):
    path = tmp_path / "attrs.h5"
    with h5py.File(path, "w") as f:
        for track in (False, True):
            g = f.create_group(f"g{int(track)}", track_order=track)
            for name, value in reversed(list(ATTRS.items())):  # creation order != name order
                if name == "vlen_ascii":
                    g.attrs.create(name, "plain", dtype=h5py.string_dtype("ascii"))
                elif name == "bad_utf8":
                    g.attrs.create(name, b"\xff\xfe", dtype=h5py.string_dtype("ascii"))
                else:
                    g.attrs[name] = value
            g.create_dataset("f64", data=np.linspace(0, 1, 7))
            g.create_dataset("f64_chunked", data=np.arange(1000.0), chunks=(100,),
                             compression="gzip", shuffle=True, fletcher32=True)
            g.create_dataset("f32", data=np.linspace(0, 1, 7, dtype=np.float32))
            g.create_dataset("f64_be", data=np.linspace(0, 1, 7).astype(">f8"))
            g.create_dataset("empty", data=np.zeros(0))
            g.create_dataset("i16", data=np.arange(5, dtype=np.int16))
            g["i16"].attrs["scale"] = 0.5
            g.create_dataset("null", dtype="f8")          # an empty dataspace
            g.create_dataset("scalar", data=1.0)
            g.create_group("sub")
    with h5py.File(path, "r") as f:
        yield f


@pytest.mark.parametrize("group", ["g0", "g1"])
def test_read_attrs_equals_h5py(h5file, group):
    g = h5file[group]
    expected = {k: g.attrs[k] for k in g.attrs}
    got = read_attrs(g.id)
    assert list(got) == list(expected)            # the same order (name or creation)
    for k, v in expected.items():
        assert type(got[k]) is type(v), k
        if isinstance(v, np.ndarray):
            assert got[k].dtype == v.dtype and np.array_equal(got[k], v), k
        elif isinstance(v, h5py.Empty):
            assert got[k] == v
        else:
            assert got[k] == v, k


def test_read_attrs_only_reads_the_names_asked_in_their_order(h5file):
    g = h5file["g0"]
    got = read_attrs(g.id, only=("i64", "missing", "f64"))
    assert list(got) == ["i64", "f64"]
    assert got == {"i64": 3, "f64": 2000.0}


def test_members_and_float64_reads_equal_h5py(h5file):
    g = h5file["g0"]
    for name in ("f64", "f64_chunked", "f32", "f64_be", "empty", "i16"):
        m = open_member(g.id, name)
        d = g[name]
        assert m.is_dataset and m.shape == d.shape and m.ndim == d.ndim and m.dtype == d.dtype
        got = read_float64(m)
        want = np.asarray(d[()], dtype=np.float64)
        assert got.dtype == np.float64 and got.shape == want.shape
        assert np.array_equal(got, want)
    for name in ("null", "scalar"):        # refused by the checks, never read: described
        m, d = open_member(g.id, name), g[name]
        assert m.is_dataset and m.shape == d.shape and m.ndim == d.ndim and m.dtype == d.dtype
    described = open_member(g.id, "f64").closed()       # what the checks keep of a member
    assert described.id is None and described.shape == (7,) and described.ndim == 1
    assert described.dtype == np.float64 and described.is_dataset
    sub = open_member(g.id, "sub")
    assert not sub.is_dataset and sub.shown_shape == "a group" and sub.dtype is None
    assert open_group(g.id, "sub") is not None and open_group(g.id, "f64") is None
    assert has_attr(open_member(g.id, "i16").id, "scale")
    assert not has_attr(open_member(g.id, "f64").id, "scale")


def test_a_corrupted_chunk_is_refused_by_the_fast_read(tmp_path):
    """The fast read verifies Fletcher-32 like any read: a flipped byte is an error."""
    path = tmp_path / "flip.h5"
    data = np.linspace(0.0, 1.0, 4096)
    with h5py.File(path, "w") as f:
        f.create_dataset("x", data=data, chunks=(4096,), fletcher32=True)
        offset = f["x"].id.get_chunk_info(0).byte_offset
    raw = bytearray(path.read_bytes())
    raw[offset + 100] ^= 0xFF
    path.write_bytes(bytes(raw))
    with h5py.File(path, "r") as f:
        m = open_member(f.id, "x")
        with pytest.raises(OSError):
            read_float64(m)


def test_float64_buffers_give_each_plain_dataset_its_own_view(h5file):
    """One array cut into a view per plain float64 dataset; each read lands in its own
    view (no two share a sample), the others are read on their own."""
    g = h5file["g0"]
    names = ("f64", "f64_chunked", "f32", "empty", "f64")
    members = [open_member(g.id, k) for k in names]
    views = float64_buffers(members)
    assert set(views) == {id(members[0]), id(members[1]), id(members[4])}
    got = [read_float64(m, views.get(id(m))) for m in members]
    for name, arr in zip(names, got, strict=True):
        assert np.array_equal(arr, np.asarray(g[name][()], dtype=np.float64))
    assert got[0].base is not None and got[0].base is got[1].base is got[4].base
    assert not np.shares_memory(got[0], got[1]) and not np.shares_memory(got[0], got[4])


# -- the structural checks and the reader on the low-level path --------------------------
def _small_session(tmp_path):
    from nmsid.testing.sessions import write_synthetic_session
    path = tmp_path / "small.h5"
    write_synthetic_session(path, seed=3, sE_levels=(0.4, 0.7), repeats=1, steady_s=1.0,
                            chirp_s=1.0)
    return path


def test_a_trial_that_is_not_a_group_is_named(tmp_path):
    from nmsid.protocols.session_file import SessionFileError, read_session, validate_session
    path = _small_session(tmp_path)
    with h5py.File(path, "a") as f:
        del f["trials/t001"]
        f["trials/t001"] = np.zeros(10)
    assert "/trials/t001 is not a group" in validate_session(path, fatal_only=True)
    with pytest.raises(SessionFileError, match="/trials/t001 is not a group"):
        read_session(path)


def test_a_required_dataset_that_is_not_float_is_named(tmp_path):
    """The contract: every required dataset is 1-D float64 (float32 is read as float64;
    integers are refused: they need a scale, which only the optional signals have)."""
    from nmsid.protocols.session_file import SessionFileError, read_session, validate_session
    path = _small_session(tmp_path)
    with h5py.File(path, "a") as f:
        n = f["trials/t002/rE"].shape[0]
        del f["trials/t002/rE"]
        f["trials/t002/rE"] = np.ones(n, dtype=np.int32)
    problems = validate_session(path, fatal_only=True)
    assert "/trials/t002/rE must be float64, got int32" in problems
    with pytest.raises(SessionFileError, match="/trials/t002/rE must be float64"):
        read_session(path)


def test_a_trial_gone_between_the_checks_and_the_read_is_a_damaged_file(tmp_path,
                                                                         monkeypatch):
    """The reader reopens each trial the checks found; if it is no longer a group there
    (another program changed the file meanwhile) the file is reported damaged, by name."""
    from nmsid.protocols import session_reader
    from nmsid.protocols.session_file import SessionFileError
    path = _small_session(tmp_path)
    monkeypatch.setattr(session_reader, "open_group", lambda gid, name: None)
    with pytest.raises(SessionFileError, match="damaged: data cannot be read.*t001"):
        session_reader.read_session(path)
