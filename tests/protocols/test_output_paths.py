"""protocols.output_paths: no command overwrites what the user did not ask to replace."""

import os

import h5py
import pytest

from nmsid.protocols.errors import OutputPathError
from nmsid.protocols.output_paths import (
    MANIFEST_NAME,
    TMP_PREFIX,
    check_output,
    is_session_file,
    output_dir,
    output_file,
    write_manifest,
)
from nmsid.testing.platforms import WINE_SYMLINK


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
    write_manifest(d)  # as if an earlier nmsid command had written it
    with pytest.raises(OutputPathError, match="not empty; give --force"):
        with output_dir(d):
            pass
    with pytest.raises(RuntimeError):
        with output_dir(d, force=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise RuntimeError("killed")
    assert sorted(p.name for p in d.iterdir()) == [MANIFEST_NAME, "old.txt"]
    with output_dir(d, force=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in d.iterdir()) == [MANIFEST_NAME, "new.txt"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TMP_PREFIX)]
    # a folder holding a session file is never replaced
    _session(d / "keep.h5")
    with pytest.raises(OutputPathError, match="holds the session file"):
        check_output(d, force=True, kind="folder")


def test_force_replaces_only_a_folder_nmsid_wrote(tmp_path):
    """Issue 39: `--out study/ --force` run from the repository root replaced the package's
    own source folder. A folder without nmsid's manifest, or with a file the manifest does
    not list, is refused with --force and left byte for byte as it was."""
    src = tmp_path / "study"
    src.mkdir()
    (src / "__init__.py").write_text("x = 1\n")
    (src / "sub").mkdir()
    (src / "sub" / "runner.py").write_text("y = 2\n")
    with pytest.raises(OutputPathError, match="nmsid did not write this folder") as err:
        with output_dir(src, force=True) as tmp:
            (tmp / "report.html").write_text("new")
    assert "\n" not in str(err.value)
    assert (src / "__init__.py").read_text() == "x = 1\n"
    assert (src / "sub" / "runner.py").read_text() == "y = 2\n"
    assert sorted(p.name for p in src.iterdir()) == ["__init__.py", "sub"]
    # nmsid's own output, written twice: the second --force replaces it
    out = tmp_path / "results"
    with output_dir(out, command="identify") as tmp:
        (tmp / "twin.json").write_text("{}")
        (tmp / "figs").mkdir()
        (tmp / "figs" / "a.png").write_text("png")
    with output_dir(out, force=True) as tmp:
        (tmp / "twin.json").write_text("{2}")
    assert (out / "twin.json").read_text() == "{2}" and not (out / "figs").exists()
    # ... but not once the user has put a file of theirs in it, even deep inside
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputPathError, match="holds notes.txt, which nmsid did not write"):
        with output_dir(out, force=True) as tmp:
            (tmp / "twin.json").write_text("{3}")
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "twin.json").read_text() == "{2}"
    # a damaged manifest is no manifest
    (out / "notes.txt").unlink()
    (out / MANIFEST_NAME).write_text("not json")
    with pytest.raises(OutputPathError, match="nmsid did not write"):
        check_output(out, force=True, kind="folder")
