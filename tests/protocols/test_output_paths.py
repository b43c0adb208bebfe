"""protocols.output_paths: no command overwrites what the user did not ask to replace."""

import os

import h5py
import pytest

from nmsid.protocols.errors import OutputPathError
from nmsid.testing.platforms import WINE_SYMLINK
from nmsid.protocols.output_paths import (TMP_PREFIX, check_output, is_session_file, output_dir,
                                          output_file)


def _session(path):
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "nmsid-session"
    return path


def test_existing_file_needs_force_and_a_session_file_never_goes(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("old")
    with pytest.raises(OutputPathError, match="exists; give --force"):
        check_output(f)
    assert check_output(f, force=True) == f
    s = _session(tmp_path / "s.h5")
    assert is_session_file(s) and not is_session_file(f)
    with pytest.raises(OutputPathError, match="never overwrites a session file"):
        check_output(s, force=True)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as fh:
        fh.attrs["format"] = "something-else"
    assert not is_session_file(other)


@pytest.mark.wine_gap(WINE_SYMLINK)
def test_a_dangling_link_is_refused(tmp_path):
    link = tmp_path / "link.csv"
    try:
        link.symlink_to(tmp_path / "missing" / "x.csv")
    except OSError as exc:  # Windows: WinError 1314 without the privilege
        pytest.skip("Windows: creating a symbolic link needs Developer Mode or an "
                    f"administrator ({exc})")
    with pytest.raises(OutputPathError, match="dangling symbolic link"):
        check_output(link)


def test_a_kind_mismatch_is_refused(tmp_path):
    with pytest.raises(OutputPathError, match="is a folder"):
        check_output(tmp_path)
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    with pytest.raises(OutputPathError, match="is a file"):
        check_output(plain, kind="folder")


@pytest.mark.posix_only("a folder's read-only attribute does not stop Windows writing in it")
def test_an_unwritable_folder_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        with pytest.raises(OutputPathError, match="cannot write in"):
            check_output(ro / "x.csv")
    finally:
        ro.chmod(0o700)


def test_output_file_replaces_only_on_success(tmp_path):
    f = tmp_path / "r.csv"
    f.write_text("old")
    with pytest.raises(RuntimeError):
        with output_file(f, force=True) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert f.read_text() == "old"
    with output_file(f, force=True) as tmp:
        tmp.write_text("new")
    assert f.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]


def test_output_dir_never_mixes_old_and_new(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    (d / "old.txt").write_text("old")
    with pytest.raises(OutputPathError, match="not empty; give --force"):
        with output_dir(d):
            pass
    with pytest.raises(RuntimeError):
        with output_dir(d, force=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise RuntimeError("killed")
    assert sorted(p.name for p in d.iterdir()) == ["old.txt"]
    with output_dir(d, force=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in d.iterdir()) == ["new.txt"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TMP_PREFIX)]
    # a folder holding a session file is never replaced
    _session(d / "keep.h5")
    with pytest.raises(OutputPathError, match="holds the session file"):
        check_output(d, force=True, kind="folder")
