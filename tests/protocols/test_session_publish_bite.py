"""Tests that bite (issue 29, 5) for publishing (protocols/session_publish.py): the
free-space check refuses exactly below the need, and a failed write leaks no file
handle (on Windows an open handle keeps the temp file, and the folder, in use)."""

from __future__ import annotations

import errno
import os

import pytest

import nmsid.protocols.session_publish as pub
from nmsid.protocols.errors import DiskFullError, SessionWriteError

IMAGE = b"new version" * 100


def test_publish_takes_a_disk_with_exactly_the_space_it_needs(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    need = len(IMAGE) + pub.SPACE_MARGIN_BYTES
    monkeypatch.setattr(pub, "free_bytes", lambda folder: need)
    pub.publish_image(path, IMAGE, exclusive=True)
    assert path.read_bytes() == IMAGE


def test_publish_refuses_a_disk_one_byte_short_and_leaves_the_file(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    path.write_bytes(b"old")
    need = len(IMAGE) + pub.SPACE_MARGIN_BYTES
    monkeypatch.setattr(pub, "free_bytes", lambda folder: need - 1)
    with pytest.raises(DiskFullError):
        pub.publish_image(path, IMAGE)
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


def test_a_failed_write_closes_its_temp_file(tmp_path, monkeypatch):
    opened = _spy_temp_fds(monkeypatch)

    def failing_fsync(fd):
        raise OSError(errno.EIO, "I/O error")
    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(SessionWriteError):
        pub.publish_image(tmp_path / "s.h5", IMAGE)
    monkeypatch.undo()
    assert len(opened) == 1
    with pytest.raises(OSError):
        os.fstat(opened[0])         # closed: no handle left on the temp file
    assert list(tmp_path.iterdir()) == []


def _spy_temp_fds(monkeypatch) -> list[int]:
    opened: list[int] = []
    real_open = os.open

    def spy_open(p, *a, **kw):
        fd = real_open(p, *a, **kw)
        if pub.TEMP_TAG in os.fspath(p):
            opened.append(fd)
        return fd
    monkeypatch.setattr(os, "open", spy_open)
    return opened


def test_a_published_file_leaves_no_handle_open(tmp_path, monkeypatch):
    opened = _spy_temp_fds(monkeypatch)
    pub.publish_image(tmp_path / "s.h5", IMAGE, exclusive=True)
    pub.publish_image(tmp_path / "s.h5", IMAGE + b"!")
    monkeypatch.undo()
    assert len(opened) == 2
    for fd in opened:
        with pytest.raises(OSError):
            os.fstat(fd)


def test_a_failed_rename_never_closes_a_file_it_does_not_own(tmp_path, monkeypatch):
    """The temp file's descriptor number, once closed, is reused by the next open (the
    lowest free number: POSIX, and the Windows C runtime): a failure after the close must
    not close it again, or another part of the program loses its file."""
    other: list[int] = []

    def failing_replace(src, dst, *a, **kw):
        other.append(os.open(tmp_path / "someone-elses.txt", os.O_WRONLY | os.O_CREAT))
        raise OSError(errno.EIO, "I/O error")
    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(SessionWriteError):
        pub.publish_image(tmp_path / "s.h5", IMAGE, delays_s=())
    monkeypatch.undo()
    try:
        os.fstat(other[0])          # still open: not closed by the failed publish
    finally:
        os.close(other[0])


def test_a_temp_file_that_cannot_be_created_is_a_one_line_write_error(tmp_path, monkeypatch):
    """A folder the user may not write in (or an antivirus refusing the create)."""
    def refused_open(p, *a, **kw):
        raise PermissionError(errno.EACCES, "Permission denied", os.fspath(p))
    monkeypatch.setattr(os, "open", refused_open)
    with pytest.raises(SessionWriteError, match="cannot be written"):
        pub.publish_image(tmp_path / "s.h5", IMAGE)
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_a_new_session_over_an_existing_file_is_refused_before_a_byte_is_written(
        tmp_path, monkeypatch):
    from nmsid.protocols.session_file import SessionExistsError  # noqa: PLC0415
    path = tmp_path / "s.h5"
    path.write_bytes(b"old")
    opened = _spy_temp_fds(monkeypatch)
    with pytest.raises(SessionExistsError):
        pub.publish_image(path, IMAGE, exclusive=True)
    assert opened == [] and path.read_bytes() == b"old"
